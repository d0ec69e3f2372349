"""Figures about models: fits, reconstructed joints, end-effector paths, diagnosis.

Every figure has axes labels with units, a legend and a title, and is written as PNG with the
non-interactive Agg backend.  matplotlib is imported inside the functions.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.floating[Any]]


def _plt() -> Any:
    # lazy: heavy (matplotlib)
    import matplotlib

    matplotlib.use("Agg")
    # lazy: heavy (matplotlib)
    import matplotlib.pyplot as plt

    return plt


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(text).stem if text.endswith(".json") else text)[
        :60
    ]


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def plot_outputs(
    out_dir: Path,
    name: str,
    t: FloatArray,
    y: FloatArray,
    y_hat: dict[str, FloatArray],
    outputs: Sequence[str],
    units: Sequence[str] | None = None,
    title: str = "Measured and simulated outputs",
) -> Path:
    """Measured outputs and one or more model simulations over time, one panel per output."""
    fig = _output_panels(t, y, y_hat, outputs, units, title)
    return _save(fig, out_dir / f"outputs_{_slug(name)}.png")


def _output_panels(
    t: FloatArray,
    y: FloatArray,
    y_hat: dict[str, FloatArray],
    outputs: Sequence[str],
    units: Sequence[str] | None,
    title: str,
    band: tuple[FloatArray, str] | None = None,
) -> Any:
    """One panel per output: measured, the simulations, and a band (half-width, label)
    around the first simulation."""
    plt = _plt()
    ny = y.shape[1]
    fig, axes = plt.subplots(ny, 1, figsize=(10, 2.6 * ny), sharex=True, squeeze=False)
    for j in range(ny):
        ax = axes[j, 0]
        ax.plot(t, y[:, j], color="black", lw=1.0, label="measured")
        for label, yh in y_hat.items():
            ax.plot(t, yh[:, j], lw=1.0, label=label)
        if band is not None:
            centre, (half, label) = next(iter(y_hat.values()))[:, j], band
            ax.fill_between(t, centre - half[:, j], centre + half[:, j], alpha=0.3, label=label)
        unit = units[j] if units and units[j] else "signal units"
        ax.set_ylabel(f"{outputs[j]} [{unit}]")
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title(title)
    return fig


def plot_structure_selection(
    out_dir: Path, name: str, candidates: Sequence[dict[str, Any]]
) -> Path:
    """Held-out and estimation error against model order, one line per structure family.

    ``candidates`` is the table a structure-selecting identifier stores in its provenance
    (``details["candidates"]``: ``order``, ``integrator``, ``estimation_rms``,
    ``held_out_rms``, ``selected`` for ``pem``; ``na``, ``nb``, ``held_out_rms`` for ``arx``,
    drawn against ``na`` with a line per ``nb``); the selected candidate is circled.
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    families: dict[str, list[dict[str, Any]]] = {}
    arx = any("na" in row for row in candidates)
    for row in candidates:
        if "held_out_rms" not in row or not np.isfinite(row["held_out_rms"]):
            continue
        if arx:  # ARX orders: the error against na, one line per nb
            row = {**row, "order": row["na"]}
            label = f"nb = {max(row['nb'])}"
        else:
            label = "with integrator(s)" if row.get("integrator") else "stable"
        families.setdefault(label, []).append(row)
    for label, rows in families.items():
        rows = sorted(rows, key=lambda r: r["order"])
        orders = [r["order"] for r in rows]
        (line,) = ax.semilogy(
            orders, [r["held_out_rms"] for r in rows], "o-", label=f"held out, {label}"
        )
        if all("estimation_rms" in r for r in rows):
            ax.semilogy(
                orders,
                [r["estimation_rms"] for r in rows],
                "x--",
                color=line.get_color(),
                alpha=0.6,
                label=f"estimation, {label}",
            )
        for r in rows:
            if r.get("selected"):
                ax.plot(
                    r["order"], r["held_out_rms"], "o", ms=14, mfc="none", mec="red", mew=2,
                    label="selected",
                )  # fmt: skip
    ax.set_xlabel("na (past outputs)" if arx else "order (states)")
    ax.set_ylabel("normalised RMS error [-]")
    ax.set_title(f"Structure selection: {name}")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, ncol=2 if len(families) > 4 else 1)
    return _save(fig, out_dir / f"structure_{_slug(name)}.png")


def plot_singular_values(out_dir: Path, name: str, values: Sequence[float], order: int) -> Path:
    """The subspace step's singular values (log scale) with the chosen order marked."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    k = np.arange(1, len(values) + 1)
    ax.semilogy(k, values, "o-", label="singular values")
    ax.axvline(order + 0.5, color="red", ls="--", label=f"order {order}")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value [-]")
    ax.set_title(f"Subspace singular values: {name}")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return _save(fig, out_dir / f"singular_values_{_slug(name)}.png")


def plot_band(
    out_dir: Path,
    name: str,
    t: FloatArray,
    y: FloatArray,
    y_hat: FloatArray,
    half_width: FloatArray,
    outputs: Sequence[str],
    units: Sequence[str] | None = None,
    level: float = 0.99,
) -> Path:
    """Measured outputs, the simulation and its confidence band (MATLAB ``showConfidence``)."""
    fig = _output_panels(
        t, y, {"simulated": y_hat}, outputs, units,
        f"Simulation with its confidence band: {name}",
        band=(half_width, f"{level:.0%} band (parameter uncertainty)"),
    )  # fmt: skip
    return _save(fig, out_dir / f"band_{_slug(name)}.png")


def plot_bode(
    out_dir: Path,
    name: str,
    freqs: FloatArray,
    empirical: Any,
    models: dict[str, Any],
    inputs: Sequence[str],
    outputs: Sequence[str],
) -> Path:
    """Bode magnitude and phase of models over the empirical (spectral) estimate, per pair."""
    plt = _plt()
    nu, ny = len(inputs), len(outputs)
    pairs = [(j, a) for j in range(ny) for a in range(nu)]
    fig, axes = plt.subplots(
        2, len(pairs), figsize=(4.5 * len(pairs), 6), sharex=True, squeeze=False
    )
    for c, (j, a) in enumerate(pairs):
        mag, ph = axes[0, c], axes[1, c]
        g = empirical[:, j, a]
        mag.semilogx(freqs, 20 * np.log10(np.abs(g) + 1e-300), ".", color="black", ms=3,
                     label="data (spectral H1)")  # fmt: skip
        ph.semilogx(freqs, np.degrees(np.unwrap(np.angle(g))), ".", color="black", ms=3)
        for label, G in models.items():
            mag.semilogx(freqs, 20 * np.log10(np.abs(G[:, j, a]) + 1e-300), lw=1.2, label=label)
            ph.semilogx(freqs, np.degrees(np.unwrap(np.angle(G[:, j, a]))), lw=1.2)
        mag.set_title(f"{inputs[a]} → {outputs[j]}")
        mag.set_ylabel("magnitude [dB]")
        ph.set_ylabel("phase [deg]")
        ph.set_xlabel("frequency [Hz]")
        for ax in (mag, ph):
            ax.grid(alpha=0.3, which="both")
        mag.legend(fontsize=8)
    fig.suptitle(f"Frequency response: {name}")
    return _save(fig, out_dir / f"bode_{_slug(name)}.png")


def plot_joints(
    out_dir: Path, name: str, t: FloatArray, q_meas: FloatArray, q_model: FloatArray
) -> Path:
    """The paper's Fig. 3: six joints, measured vs simulated (q1, q2) and reconstructed (q3..q6)."""
    plt = _plt()
    fig, axes = plt.subplots(3, 2, figsize=(11, 7.5), sharex=True)
    for i in range(6):
        ax = axes[i // 2, i % 2]
        kind = "simulated" if i < 2 else "reconstructed"
        ax.plot(t, q_meas[:, i], color="black", lw=0.9, label="measured")
        ax.plot(t, q_model[:, i], lw=0.9, label=kind)
        plane = "pan" if i % 2 == 0 else "tilt"
        ax.set_ylabel(f"q{i + 1} [rad]")
        ax.set_title(f"joint {i + 1} ({plane})", fontsize=9)
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    fig.suptitle(f"Joint angles, modelled and reconstructed — {name}")
    return _save(fig, out_dir / f"joints_{_slug(name)}.png")


def plot_ee_path(out_dir: Path, name: str, ee_meas: FloatArray, ee_model: FloatArray) -> Path:
    """The paper's Fig. 4: end-effector path in the base x–y plane, measured vs simulated."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 6))
    ax.plot(100 * ee_meas[:, 0], 100 * ee_meas[:, 1], color="black", lw=0.8, label="measured")
    ax.plot(100 * ee_model[:, 0], 100 * ee_model[:, 1], lw=0.8, label="model + reconstruction")
    ax.set_xlabel("x [cm]")
    ax.set_ylabel("y [cm]")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"End-effector path — {name}")
    return _save(fig, out_dir / f"ee_path_{_slug(name)}.png")


def plot_residual_vs(
    out_dir: Path,
    name: str,
    signal: FloatArray,
    residual: FloatArray,
    signal_label: str,
    residual_label: str,
) -> Path:
    """Scatter of a residual against the signal that explains it, with a binned mean."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    ax.scatter(signal, residual, s=2, alpha=0.25, color="tab:blue", label="samples")
    if np.ptp(signal) > 0:
        edges = np.quantile(signal, np.linspace(0, 1, 21))
        edges = np.unique(edges)
        if len(edges) > 2:
            idx = np.clip(np.digitize(signal, edges[1:-1]), 0, len(edges) - 2)
            centers = [signal[idx == b].mean() for b in range(len(edges) - 1) if np.any(idx == b)]
            means = [residual[idx == b].mean() for b in range(len(edges) - 1) if np.any(idx == b)]
            ax.plot(centers, means, color="tab:red", lw=2, label="binned mean")
    ax.axhline(0, color="black", lw=0.6)
    ax.set_xlabel(signal_label)
    ax.set_ylabel(residual_label)
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(f"Free-run residual — {name}")
    return _save(fig, out_dir / f"residual_vs_{_slug(name)}.png")


def plot_ranking(out_dir: Path, findings: Sequence[dict[str, Any]]) -> Path:
    """Bar chart of the validation fit gain of every candidate cause (significant ones solid)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 0.45 * max(len(findings), 3) + 1.2))
    names = [f["cause"] for f in findings][::-1]
    diverged = [not math.isfinite(f["gain"]) or f.get("diverged", False) for f in findings][::-1]
    gains = [0.0 if d else max(f["gain"], -50.0) for f, d in zip(findings[::-1], diverged)]
    colors = ["tab:green" if f["significant"] else "tab:gray" for f in findings][::-1]
    ax.barh(names, gains, color=colors)
    for i, d in enumerate(diverged):
        if d:
            ax.annotate("diverged", (0, i), xytext=(4, 0), textcoords="offset points",
                        va="center", fontsize=8, color="tab:red")  # fmt: skip
    ax.axvline(0, color="black", lw=0.6)
    ax.set_xlabel("validation fit gain [percentage points]")
    ax.set_ylabel("candidate cause")
    # lazy: heavy (matplotlib)
    from matplotlib.patches import Patch

    ax.legend(
        handles=[
            Patch(color="tab:green", label="significant"),
            Patch(color="tab:gray", label="not significant"),
        ],
        loc="lower right",
        fontsize=8,
    )
    ax.set_title("Candidate causes ranked by gain on held-out data")
    ax.grid(alpha=0.3, axis="x")
    return _save(fig, out_dir / "ranking.png")


def plot_correlation(
    out_dir: Path, lags: FloatArray, corr: FloatArray, band: float, label: str, title: str
) -> Path:
    """Correlation against lag with the 99 % confidence band (as MATLAB's ``resid``)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    ax.stem(lags, corr, basefmt=" ", label=label)
    ax.axhspan(-band, band, color="tab:orange", alpha=0.2, label="99 % confidence band")
    ax.set_xlabel("lag [samples]")
    ax.set_ylabel("correlation [-]")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title(title)
    return _save(fig, out_dir / f"corr_{_slug(label)}.png")


def __getattr__(name: str) -> Any:
    # The robot's figures lived here in 0.1 (now tendonkit.robot.figures), for one release.
    from ._compat import moved_name

    return moved_name(__name__, name)
