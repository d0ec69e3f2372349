"""Co-simulation master: fmpy steps the plant FMU, a controller runs in Python between steps.

Every 30 ms (the plant FMU's fixed communication step) the master reads the plant's measured
outputs, asks the controller for the tendon forces and writes them to ``T_cmd1..T_cmd4``
before the next ``doStep``.  The plant has no direct feedthrough from force to angle, so the
outputs read at ``t_k`` are those of the state at ``t_k`` and the loop is causal.

References (end-effector curves converted to q1, q2 references with the constant-ratio
inverse kinematics, as in the paper): ``petal`` (rose curve ``r = A cos(kθ)``), ``circle`` and
``step``.  The open-loop kinematic controller of the data-collection protocol is available as
a baseline on the same plant and reference (:func:`open_loop`).

Fault handling: a solver failure or infeasibility makes the controller hold its last input;
the master counts those fallbacks and reports them; inputs are clipped to their bounds before
they reach the plant and any attempt to leave them is counted as a violation (must be 0).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from tendonkit.errors import FMUError, OptionError

FloatArray = NDArray[np.float64]

STEP = 0.03
INPUTS = ("T_cmd1", "T_cmd2", "T_cmd3", "T_cmd4")
OUTPUTS = ("q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z", "T1", "T2", "T3", "T4")
TRUTH = ("q1_true", "q2_true", "ee_x_true", "ee_y_true", "ee_z_true")
REFERENCES = ("petal", "circle", "step")
DEADLINE_S = 0.030


class Controller(Protocol):
    """What the master needs from a controller (``tendonkit.mpc`` controllers provide it)."""

    horizon: int

    def reset(self, u0: Any = None, y0: Any = None) -> None:
        """Start from input ``u0`` and measurement ``y0``."""

    def step(self, y_meas: Any, r_future: Any) -> Any:
        """One control step: returns an object with ``u``, ``fallback``, ``solve_time_s``."""


@dataclass(frozen=True)
class Reference:
    """A reference for q1, q2 and the end effector, sampled every ``dt`` seconds."""

    name: str
    t: FloatArray
    q12: FloatArray  # (n, 2) rad
    ee: FloatArray  # (n, 3) m
    u_open_loop: FloatArray  # (n, 4) N: the kinematic controller's commands

    def preview(self, k: int, horizon: int) -> FloatArray:
        """References for the next ``horizon`` samples after ``k`` (last value repeated)."""
        idx = np.minimum(np.arange(k + 1, k + 1 + horizon), len(self.t) - 1)
        return self.q12[idx]


def make_reference(
    kind: str, *, duration: float | None = None, amplitude: float = 0.09, petals: int = 3
) -> Reference:
    """Build a reference: ``petal``, ``circle`` or ``step`` (spec §12, MPC test reference).

    Parameters
    ----------
    kind : str
        One of :data:`REFERENCES`.
    duration : float, optional
        Truncate or repeat to this many seconds.
    amplitude : float
        Petal amplitude A or circle radius, metres.
    petals : int
        The rose parameter k of the petal.
    """
    from tendonkit import protocol
    from tendonkit.kinematics import commanded_tensions, forward_kinematics

    if kind not in REFERENCES:
        raise OptionError(f"Unknown reference {kind!r}; choose one of {', '.join(REFERENCES)}.")
    if kind == "petal":
        p = protocol.petal(petals=petals, amplitude=amplitude)
        q12, ee, u = p.q_ref[:, :2], p.ee_ref, p.u
    elif kind == "circle":
        p = protocol.circles(radii=[amplitude], laps=2)
        q12, ee, u = p.q_ref[:, :2], p.ee_ref, p.u
    else:
        n = round((duration or 12.0) / STEP)
        q12 = np.zeros((n, 2))
        quarter = max(n // 4, 1)
        q12[quarter : 2 * quarter, 0] = 0.15
        q12[2 * quarter : 3 * quarter, 1] = -0.15
        q12[3 * quarter :, :] = (0.1, 0.1)
        from tendonkit.kinematics import expand_joints

        ee = forward_kinematics(expand_joints(q12))
        u = commanded_tensions(q12, 105.0)
    if duration is not None:
        n = round(duration / STEP)
        reps = int(np.ceil(n / len(q12)))
        q12, ee, u = (np.concatenate([a] * reps)[:n] for a in (q12, ee, u))
    t = np.asarray(STEP * np.arange(len(q12)), dtype=np.float64)
    return Reference(kind, t, np.asarray(q12, float), np.asarray(ee, float), np.asarray(u, float))


@dataclass
class CosimResult:
    """Time series and summary figures of one closed-loop (or open-loop) run."""

    controller: str
    reference: Reference
    y: FloatArray  # measured q1..q6, ee_x..ee_z, T1..T4 per step (n, 13)
    truth: FloatArray  # q1_true, q2_true, ee_true (n, 5)
    u: FloatArray  # applied T_cmd (n, 4)
    solve_times: FloatArray
    step_times: FloatArray
    fallbacks: int
    violations: int
    wall_time_s: float
    statuses: dict[str, int] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """The figures the ``mpc`` command reports (JSON-ready)."""
        r = self.reference
        e = self.y[:, :2] - r.q12
        ee_err = np.linalg.norm(self.y[:, 6:9] - r.ee, axis=1)
        ms = 1e3 * self.solve_times
        duration = len(r.t) * STEP
        out: dict[str, Any] = {
            "controller": self.controller,
            "reference": r.name,
            "duration_s": duration,
            "rms_error_rad": {
                "q1": float(np.sqrt(np.mean(e[:, 0] ** 2))),
                "q2": float(np.sqrt(np.mean(e[:, 1] ** 2))),
            },
            "rms_error_true_rad": {
                "q1": float(np.sqrt(np.mean((self.truth[:, 0] - r.q12[:, 0]) ** 2))),
                "q2": float(np.sqrt(np.mean((self.truth[:, 1] - r.q12[:, 1]) ** 2))),
            },
            "mean_ee_error_cm": float(100 * np.mean(ee_err)),
            "fallbacks": int(self.fallbacks),
            "input_bound_violations": int(self.violations),
            "realtime_factor": float(duration / self.wall_time_s) if self.wall_time_s > 0 else None,
            "statuses": self.statuses,
        }
        if len(ms):
            out["solve_time_ms"] = {
                "median": float(np.median(ms)),
                "p99": float(np.percentile(ms, 99)),
                "max": float(np.max(ms)),
            }
            out["step_time_ms"] = {
                "median": float(np.median(1e3 * self.step_times)),
                "p99": float(np.percentile(1e3 * self.step_times, 99)),
                "max": float(np.max(1e3 * self.step_times)),
            }
            out["deadline_misses"] = int(np.sum(self.step_times > DEADLINE_S))
        return out


class PlantFMU:
    """A plant FMU instance driven step by step through fmpy's FMI 2.0 co-simulation API."""

    def __init__(self, path: str | Path, parameters: Mapping[str, Any] | None = None) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        path = Path(path)
        if not path.exists():
            raise FMUError(f"Plant FMU {str(path)!r} does not exist.")
        try:
            md = read_model_description(str(path))
        except Exception as exc:  # fmpy raises various errors for broken archives
            raise FMUError(f"{path} is not a readable FMU: {exc}") from None
        self._vars = {v.name: v for v in md.modelVariables}
        missing = [n for n in (*INPUTS, *OUTPUTS, *TRUTH) if n not in self._vars]
        if missing:
            raise FMUError(
                f"{path} is not a tendonkit plant FMU; missing variables: {', '.join(missing)}."
            )
        self._md = md
        self._dir = extract(str(path))
        self._fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=self._dir,
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="plant",
        )
        self._params = dict(parameters or {})
        unknown = [
            k for k in self._params if k not in self._vars or self._vars[k].causality != "parameter"
        ]
        if unknown:
            params = sorted(k for k, v in self._vars.items() if v.causality == "parameter")
            raise OptionError(
                f"Unknown plant parameters {unknown}; the plant FMU has: {', '.join(params)}."
            )
        self._vr_in = [self._vars[n].valueReference for n in INPUTS]
        self._vr_out = [self._vars[n].valueReference for n in (*OUTPUTS, *TRUTH)]
        self.t = 0.0

    def start(self) -> FloatArray:
        """Instantiate, apply parameters, initialise; returns the outputs at t = 0."""
        f = self._fmu
        f.instantiate()
        f.setupExperiment(startTime=0.0)
        for name, value in self._params.items():
            v = self._vars[name]
            vr = [v.valueReference]
            if v.type == "Real":
                f.setReal(vr, [float(value)])
            elif v.type in ("Integer", "Enumeration"):
                f.setInteger(vr, [int(value)])
            elif v.type == "Boolean":
                f.setBoolean(vr, [bool(int(value)) if isinstance(value, str) else bool(value)])
            else:
                f.setString(vr, [str(value)])
        f.enterInitializationMode()
        f.exitInitializationMode()
        self.t = 0.0
        return np.asarray(f.getReal(self._vr_out))

    def step(self, u: FloatArray) -> FloatArray:
        """Apply ``u`` over one 30 ms step; returns the outputs at the end of it."""
        self._fmu.setReal(self._vr_in, [float(x) for x in u])
        self._fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=STEP)
        self.t += STEP
        return np.asarray(self._fmu.getReal(self._vr_out))

    def close(self) -> None:
        """Terminate and free the instance."""
        try:
            self._fmu.terminate()
        finally:
            self._fmu.freeInstance()


def run(
    plant_fmu: str | Path,
    reference: Reference,
    controller: Controller | None = None,
    *,
    parameters: Mapping[str, Any] | None = None,
    u_min: float = 20.0,
    u_max: float = 190.0,
    name: str = "controller",
    progress: bool = False,
) -> CosimResult:
    """Run ``controller`` (or the open-loop kinematic controller when None) against the plant.

    The controller measures q1 and q2 (the model's outputs, matched by name) and commands the
    four tendon forces (the model's inputs, matched by name to ``T1..T4``/``u1..u4`` order).
    """
    from tqdm import tqdm

    plant = PlantFMU(plant_fmu, parameters)
    n = len(reference.t)
    width = len(OUTPUTS) + len(TRUTH)
    Y = np.empty((n, width))
    U = np.empty((n, 4))
    solve, steps = [], []
    fallbacks = violations = 0
    statuses: dict[str, int] = {}
    t0 = time.perf_counter()
    try:
        y = plant.start()
        u_prev = reference.u_open_loop[0].copy()
        if controller is not None:
            controller.reset(u0=u_prev, y0=y[:2])
        for k in tqdm(range(n), desc=name, disable=not progress, unit="step", leave=False):
            Y[k] = y
            if controller is None:
                u = reference.u_open_loop[k]
            else:
                res = controller.step(y[:2], reference.preview(k, controller.horizon))
                u = np.asarray(res.u, dtype=float)
                fallbacks += int(bool(res.fallback))
                solve.append(float(res.solve_time_s))
                steps.append(float(getattr(res, "step_time_s", res.solve_time_s)))
                statuses[str(res.status)] = statuses.get(str(res.status), 0) + 1
            if np.any(u < u_min - 1e-9) or np.any(u > u_max + 1e-9) or not np.all(np.isfinite(u)):
                violations += 1
                u = np.clip(np.where(np.isfinite(u), u, u_prev), u_min, u_max)
            U[k] = u
            u_prev = u
            y = plant.step(u)
    finally:
        plant.close()
    wall = time.perf_counter() - t0
    return CosimResult(
        controller=name,
        reference=reference,
        y=Y[:, : len(OUTPUTS)],
        truth=Y[:, len(OUTPUTS) :],
        u=U,
        solve_times=np.asarray(solve),
        step_times=np.asarray(steps),
        fallbacks=fallbacks,
        violations=violations,
        wall_time_s=wall,
        statuses=statuses,
    )


def open_loop(plant_fmu: str | Path, reference: Reference, **kwargs: Any) -> CosimResult:
    """The open-loop kinematic controller of the data-collection protocol on the same plant."""
    return run(plant_fmu, reference, None, name="open-loop kinematic", **kwargs)
