"""Kinematic reconstruction: the whole robot from a 2-DoF model, as in the paper.

The paper models only q1 (pan) and q2 (tilt) and recovers the other joints with constant
ratios — q3 = r3 q1, q5 = r5 q1 in the pan plane, q4 = r4 q2, q6 = r6 q2 in the tilt plane —
then the end effector with forward kinematics (one implementation, shared with the plant:
:mod:`tendonkit.robot.kinematics`).  The ratios default to the paper's values and can be estimated
from any data set that has all six joints, two ways:

- ``least_squares``: per plane, the slope through the origin, ``r = Σ q1 qi / Σ q1²``;
- ``extremes`` (the paper's "observed extremes"): the peak-to-peak range of each joint over
  the peak-to-peak range of its plane's base joint.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset
from ..errors import DataError
from ..figures import plot_ee_path, plot_joints
from ..metrics import fit
from . import PAPER_RATIOS
from .kinematics import expand_joints, forward_kinematics

FloatArray = NDArray[np.float64]

JOINTS = ("q1", "q2", "q3", "q4", "q5", "q6")
EE = ("ee_x", "ee_y", "ee_z")
#: Joint i (3..6) -> its plane's base joint (1 = pan, 2 = tilt).
BASE_OF = {"q3": "q1", "q5": "q1", "q4": "q2", "q6": "q2"}


@dataclass(frozen=True)
class Ratios:
    """Constant joint ratios ``q3/q1``, ``q4/q2``, ``q5/q1``, ``q6/q2``.

    Examples
    --------
    >>> Ratios().as_tuple()
    (1.0, 1.0, 0.6493, 0.6442, 0.2053, 0.2291)
    """

    r3: float = PAPER_RATIOS[2]
    r4: float = PAPER_RATIOS[3]
    r5: float = PAPER_RATIOS[4]
    r6: float = PAPER_RATIOS[5]

    def as_tuple(self) -> tuple[float, float, float, float, float, float]:
        """Per-joint multipliers in joint order (1, 1, r3, r4, r5, r6)."""
        return (1.0, 1.0, self.r3, self.r4, self.r5, self.r6)

    def to_dict(self) -> dict[str, float]:
        """``{"q3": r3, "q4": r4, "q5": r5, "q6": r6}``."""
        return {"q3": self.r3, "q4": self.r4, "q5": self.r5, "q6": self.r6}

    @classmethod
    def from_dict(cls, data: Any, source: str = "ratios") -> Ratios:
        """From ``{"q3": .., "q4": .., "q5": .., "q6": ..}``; every problem is reported."""
        problems = []
        if not isinstance(data, dict):
            raise DataError(f"{source}: expected an object with keys q3, q4, q5, q6.")
        for key in ("q3", "q4", "q5", "q6"):
            v = data.get(key)
            if isinstance(v, bool) or not isinstance(v, int | float) or not np.isfinite(v):
                problems.append(f"{key}: expected a finite number, found {v!r}.")
        unknown = set(data) - {"q3", "q4", "q5", "q6"}
        if unknown:
            problems.append(f"unknown keys {sorted(unknown)}; expected q3, q4, q5, q6.")
        if problems:
            raise DataError(f"{source} is not a valid ratios file:", problems)
        return cls(float(data["q3"]), float(data["q4"]), float(data["q5"]), float(data["q6"]))

    @classmethod
    def load(cls, path: str | Path) -> Ratios:
        """Read a ratios JSON file (plain data; nothing is evaluated)."""
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise DataError(f"Ratios file {str(path)!r} does not exist.") from None
        except (OSError, ValueError) as exc:
            raise DataError(f"Ratios file {str(path)!r} cannot be read: {exc}") from None
        return cls.from_dict(data, str(path))


def estimate_ratios(q: FloatArray) -> dict[str, Ratios]:
    """Both estimates of the constant ratios from measured joints ``q`` (n, 6).

    Returns
    -------
    dict
        ``{"least_squares": Ratios, "extremes": Ratios}``.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != 6 or q.shape[0] < 3:
        raise DataError(f"Ratio estimation needs all six joints, shape (n, 6); found {q.shape}.")
    if not np.all(np.isfinite(q)):
        raise DataError("Ratio estimation needs finite joint angles.")
    ls, ex = {}, {}
    for name, base in BASE_OF.items():
        i, b = JOINTS.index(name), JOINTS.index(base)
        den = float(np.dot(q[:, b], q[:, b]))
        if den == 0 or np.ptp(q[:, b]) == 0:
            raise DataError(f"{base} never moves; the ratio {name}/{base} cannot be estimated.")
        ls[name] = float(np.dot(q[:, b], q[:, i]) / den)
        ex[name] = float(np.sign(ls[name]) * np.ptp(q[:, i]) / np.ptp(q[:, b]))
    return {"least_squares": Ratios.from_dict(ls), "extremes": Ratios.from_dict(ex)}


def reconstruct(q12: FloatArray, ratios: Ratios | None = None) -> FloatArray:
    """All six joints ``(n, 6)`` from ``q1, q2`` ``(n, 2)`` with constant ratios."""
    return np.asarray(expand_joints(np.asarray(q12, dtype=float), (ratios or Ratios()).as_tuple()))


def end_effector(q12: FloatArray, ratios: Ratios | None = None) -> FloatArray:
    """End-effector position ``(n, 3)`` in metres from ``q1, q2`` via reconstruction and FK."""
    return np.asarray(forward_kinematics(reconstruct(q12, ratios)))


def ee_error_cm(ee_true: FloatArray, ee_model: FloatArray) -> float:
    """Mean Euclidean end-effector error in centimetres (the paper reports 2.48 cm)."""
    d = np.linalg.norm(np.asarray(ee_true) - np.asarray(ee_model), axis=1)
    return float(100.0 * np.mean(d))


def _base_outputs(names: Sequence[str]) -> tuple[int, int]:
    if "q1" in names and "q2" in names:
        return names.index("q1"), names.index("q2")
    raise DataError(
        f"Joint reconstruction needs model outputs named q1 and q2 (pan and tilt base joints); "
        f"the model's outputs are {', '.join(names)}."
    )


def joint_report(
    model: Any,
    data: Dataset,
    sims: Sequence[FloatArray],
    *,
    joints: bool = True,
    ee: bool = True,
    ratios: Ratios | None = None,
    plot_dir: str | Path | None = None,
    name: str = "model",
) -> dict[str, Any]:
    """Per-joint fits of the reconstructed joints and the mean end-effector error.

    ``sims`` are the model's simulated outputs per experiment of ``data`` (as from
    :func:`tendonkit.compare.score`).  Measured joints q3..q6 and the measured end effector
    (ee_x, ee_y, ee_z) are read from the data's columns; when the end effector is not in the
    data it is computed from the measured joints with forward kinematics.
    """
    ratios = ratios or Ratios()
    i1, i2 = _base_outputs(model.output_names)
    sim12 = np.vstack([s[:, [i1, i2]] for s in sims])
    q_model = reconstruct(sim12, ratios)
    out: dict[str, Any] = {"ratios": ratios.to_dict()}
    cols = set(data.columns)
    missing = [j for j in JOINTS if j not in cols]
    q_meas = None
    if not missing:
        q_meas = np.column_stack([data.signal(j) for j in JOINTS])
    if joints:
        if q_meas is None:
            raise DataError(
                f"--joints needs the measured joints {', '.join(JOINTS)} in the data; missing: "
                f"{', '.join(missing)}."
            )
        f = fit(q_meas, q_model)
        out["joint_fit"] = {j: float(v) for j, v in zip(JOINTS, f)}
        out["estimated_ratios"] = {k: r.to_dict() for k, r in estimate_ratios(q_meas).items()}
    ee_meas = None
    if all(c in cols for c in EE):
        ee_meas = np.column_stack([data.signal(c) for c in EE])
    elif q_meas is not None:
        ee_meas = forward_kinematics(q_meas)
    ee_model = forward_kinematics(q_model)
    if ee:
        if ee_meas is None:
            raise DataError(
                "--ee needs the measured end effector (ee_x, ee_y, ee_z) or all six joints in the data."
            )
        out["ee_error_cm"] = ee_error_cm(ee_meas, ee_model)
    if plot_dir is not None:
        # experiments back to back: time runs on, and path lines break between experiments
        t = data.dt * np.arange(sum(e.n_samples for e in data.experiments))
        cuts = np.cumsum([e.n_samples for e in data.experiments])[:-1]
        files = []
        if q_meas is not None:
            files.append(str(plot_joints(Path(plot_dir), name, t, q_meas, q_model)))
        if ee_meas is not None:
            gap = np.full((1, 3), np.nan)
            meas_parts = np.split(ee_meas, cuts)
            model_parts = np.split(ee_model, cuts)
            ee_m = np.vstack([np.vstack([p, gap]) for p in meas_parts])
            ee_s = np.vstack([np.vstack([p, gap]) for p in model_parts])
            files.append(str(plot_ee_path(Path(plot_dir), name, ee_m, ee_s)))
        out["figures"] = files
    return out


def joint_extras(
    *,
    joints: bool = True,
    ee: bool = True,
    ratios: Ratios | None = None,
    plot_dir: str | Path | None = None,
) -> Callable[[Any, Dataset, Sequence[FloatArray], str], dict[str, Any]]:
    """The robot's additions to each row of :func:`tendonkit.compare.compare`.

    Returns a function for its ``extras`` argument that adds :func:`joint_report` (the
    reconstructed joints' fits, the end-effector error and, with ``plot_dir``, their figures).

    Examples
    --------
    >>> from tendonkit.compare import compare
    >>> extras = joint_extras(joints=True, ee=True)  # doctest: +SKIP
    >>> compare([model], data, extras=extras)  # doctest: +SKIP
    """

    def extras(model: Any, data: Dataset, sims: Sequence[FloatArray], name: str) -> dict[str, Any]:
        return joint_report(
            model, data, sims, joints=joints, ee=ee, ratios=ratios, plot_dir=plot_dir, name=name
        )

    return extras


def has_base_joints(model: Any) -> bool:
    """True when ``model`` has the outputs q1 and q2 that the joint reconstruction needs."""
    return {"q1", "q2"} <= set(model.output_names)
