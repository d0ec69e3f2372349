"""Figures of collected data (PNG, matplotlib's Agg canvas; no global backend is changed).

:func:`fig2` draws the equivalent of the paper's Fig. 2 from a recording: the joint angles of
each plane against time, the same angles normalised by their largest magnitude (equal shapes
show the constant joint-angle ratios), and the achieved end-effector path against the
reference.  Every axis has a label with its unit, every figure a title and a legend.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DataError, OptionError

if TYPE_CHECKING:
    from .cosim import CosimResult

__all__ = ["ee_path_figure", "fig2", "joint_angle_figure"]

FloatArray = NDArray[np.float64]

_PLANES = (("pan", (1, 3, 5)), ("tilt", (2, 4, 6)))


def _new_figure(width: float, height: float) -> Any:
    # lazy: heavy (matplotlib)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _need(columns: Mapping[str, Any], names: list[str]) -> None:
    missing = [n for n in names if n not in columns]
    if missing:
        raise DataError(
            f"Cannot draw the figure: columns {', '.join(missing)} are missing. "
            f"Columns: {', '.join(columns)}."
        )


def joint_angle_figure(
    columns: Mapping[str, FloatArray], path: str | Path, title: str = ""
) -> Path:
    """Joint angles per plane against time, raw and normalised (paper Fig. 2).

    Parameters
    ----------
    columns : mapping
        ``t`` (s) and ``q1..q6`` (rad), e.g. :attr:`tendonkit.robot.collect.Recording.columns`.
    path : str or Path
        PNG file to write.
    title : str
        Added to the figure title (e.g. the protocol name).

    Returns
    -------
    Path
        ``path``.
    """
    _need(columns, ["t", *(f"q{i}" for i in range(1, 7))])
    t = np.asarray(columns["t"], dtype=float)
    fig = _new_figure(11.0, 6.5)
    axes = fig.subplots(2, 2, sharex=True)
    for col, (plane, joints) in enumerate(_PLANES):
        for i in joints:
            q = np.asarray(columns[f"q{i}"], dtype=float)
            peak = float(np.max(np.abs(q))) if q.size else 0.0
            axes[0, col].plot(t, q, lw=1.0, label=f"q{i}")
            axes[1, col].plot(t, q / peak if peak > 0 else q, lw=1.0, label=f"q{i} / max|q{i}|")
        axes[0, col].set_title(f"{plane} plane: joints {', '.join(f'q{i}' for i in joints)}")
        axes[0, col].set_ylabel("joint angle [rad]")
        axes[1, col].set_title(f"{plane} plane, normalised by the largest |q|")
        axes[1, col].set_ylabel("normalised angle [-]")
        axes[1, col].set_xlabel("time t [s]")
        for ax in axes[:, col]:
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right", fontsize="small")
    fig.suptitle("Joint angles" + (f" — {title}" if title else ""))
    fig.savefig(path, dpi=110)
    return Path(path)


def ee_path_figure(
    columns: Mapping[str, FloatArray],
    path: str | Path,
    ee_ref: FloatArray | None = None,
    title: str = "",
) -> Path:
    """Achieved end-effector path in the base x–y plane against the reference.

    Parameters
    ----------
    columns : mapping
        ``ee_x`` and ``ee_y`` (m); ``ee_x_true``/``ee_y_true`` are drawn too when present.
    path : str or Path
        PNG file to write.
    ee_ref : array, optional
        ``(n, 2+)`` reference positions, m (e.g. :attr:`tendonkit.robot.protocol.Protocol.ee_ref`).
    title : str
        Added to the figure title.

    Returns
    -------
    Path
        ``path``.
    """
    _need(columns, ["ee_x", "ee_y"])
    fig = _new_figure(6.5, 6.5)
    ax = fig.subplots()
    if ee_ref is not None:
        ref = np.asarray(ee_ref, dtype=float)
        ax.plot(100 * ref[:, 0], 100 * ref[:, 1], "k--", lw=1.0, label="reference")
    ax.plot(
        100 * np.asarray(columns["ee_x"]),
        100 * np.asarray(columns["ee_y"]),
        lw=0.8,
        label="achieved (measured)",
    )
    if "ee_x_true" in columns and "ee_y_true" in columns:
        ax.plot(
            100 * np.asarray(columns["ee_x_true"]),
            100 * np.asarray(columns["ee_y_true"]),
            lw=0.6,
            alpha=0.7,
            label="achieved (true)",
        )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize="small")
    ax.set_title("End-effector path in the base x–y plane" + (f" — {title}" if title else ""))
    fig.savefig(path, dpi=110)
    return Path(path)


def fig2(
    columns: Mapping[str, FloatArray],
    out_dir: str | Path,
    ee_ref: FloatArray | None = None,
    title: str = "",
) -> list[Path]:
    """Write the paper's Fig. 2 equivalent into ``out_dir``.

    Parameters
    ----------
    columns : mapping
        Recording columns (``t``, ``q1..q6``, ``ee_x``, ``ee_y`` …).
    out_dir : str or Path
        Folder (created if needed).
    ee_ref : array, optional
        Reference end-effector path, m.
    title : str
        Added to the figure titles.

    Returns
    -------
    list of Path
        ``joint_angles.png`` and ``ee_path.png``.

    Examples
    --------
    >>> import tempfile
    >>> t = np.arange(100) * 0.03
    >>> cols = {"t": t, **{f"q{i}": np.sin(t) / i for i in range(1, 7)},
    ...         "ee_x": np.cos(t), "ee_y": np.sin(t)}
    >>> [p.name for p in fig2(cols, tempfile.mkdtemp())]
    ['joint_angles.png', 'ee_path.png']
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [
        joint_angle_figure(columns, out / "joint_angles.png", title),
        ee_path_figure(columns, out / "ee_path.png", ee_ref, title),
    ]


def plot_tracking(
    results: Mapping[str, CosimResult] | Sequence[CosimResult], out_dir: str | Path
) -> list[Path]:
    """The paper's Fig. 5 equivalent: joint tracking and end-effector path (one PNG).

    Parameters
    ----------
    results : mapping name -> CosimResult, or sequence of CosimResult
        Runs on the same reference (e.g. the MPC and the open loop); labelled by the mapping's
        keys or by ``CosimResult.controller``.
    out_dir : str or Path
        Folder (created if needed).

    Returns
    -------
    list of Path
        ``[out_dir / "fig5_tracking.png"]``.
    """
    # lazy: heavy (matplotlib)
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    runs = (
        list(results.items())
        if isinstance(results, Mapping)
        else [(r.controller, r) for r in results]
    )
    if not runs:
        raise OptionError("plot_tracking needs at least one result.")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ref = runs[0][1].reference
    fig = Figure(figsize=(13.0, 6.5), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 2, width_ratios=(1.6, 1.0))
    ax_q = [fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0])]
    ax_ee = fig.add_subplot(grid[:, 1])
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    for j, ax in enumerate(ax_q):
        ax.plot(ref.t, ref.q12[:, j], "k--", lw=1.2, label=f"reference q{j + 1}")
        for (label, res), color in zip(runs, colors):
            rms = 1e3 * res.rms_error_true[j]
            ax.plot(
                ref.t, res.truth[:, j], color=color, lw=1.0, label=f"{label} (RMS {rms:.1f} mrad)"
            )
        ax.set_ylabel(f"q{j + 1} [rad]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    ax_q[0].set_title("Joint tracking (true joint angles)")
    ax_q[1].set_xlabel("time t [s]")
    ax_ee.plot(100 * ref.ee[:, 0], 100 * ref.ee[:, 1], "k--", lw=1.2, label="reference")
    for (label, res), color in zip(runs, colors):
        ax_ee.plot(100 * res.truth[:, 2], 100 * res.truth[:, 3], color=color, lw=1.0, label=label)
    ax_ee.set_aspect("equal", adjustable="datalim")
    ax_ee.set_xlabel("x [cm]")
    ax_ee.set_ylabel("y [cm]")
    ax_ee.grid(True, alpha=0.3)
    ax_ee.legend(loc="upper right", fontsize="small")
    ax_ee.set_title("End-effector path in the base x–y plane (true)")
    fig.suptitle(f"Tracking of the {ref.name} reference (co-simulation with the plant FMU)")
    path = out / "fig5_tracking.png"
    fig.savefig(path, dpi=110)
    return [path]
