"""Co-simulation master: fmpy steps the plant FMU, a controller runs in Python between steps.

Every 30 ms (the plant FMU's fixed communication step) the master reads the plant's measured
outputs, asks the controller for the tendon forces and writes them to ``T_cmd1..T_cmd4``
before the next ``doStep``.  The plant has no direct feedthrough from force to angle, so the
outputs read at ``t_k`` are those of the state at ``t_k`` and the loop is causal.  The plant is
driven through :class:`tendonkit.robot.collect.PlantSession` (fmpy's FMI 2.0 C API with preallocated
buffers).

References (end-effector curves converted to q1, q2 references with the constant-ratio
inverse kinematics, as in the paper): ``petal`` (rose curve ``r = A cos(kθ)``), ``circle`` and
``step``.  The open-loop kinematic controller of the data-collection protocol is available as
a baseline on the same plant and reference (:func:`open_loop`).  :func:`make_controller` builds
the linear or the nonlinear MPC for a model, with the settings tuned for this robot
(:class:`ControllerSettings`).

Fault handling: a solver failure or infeasibility makes the controller hold its last input;
the master counts those fallbacks and reports them; inputs are clipped to their bounds before
they reach the plant and any attempt to leave them is counted as a violation (must be 0).

Examples
--------
>>> ref = make_reference("petal", duration=20.0, speed=0.08)
>>> ref.q12.shape, round(ref.duration, 2)
((667, 2), 20.01)
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import FMUError, OptionError, raise_if
from . import protocol
from .collect import OUTPUTS as ALL
from .collect import PlantSession
from .controllers import (
    DEFAULTS,
    PAIR_SUMS,
    PRETENSION,
    ControllerSettings,
    controller_kind,
    make_controller,
)
from .figures import plot_tracking
from .kinematics import commanded_tensions, expand_joints, forward_kinematics

__all__ = [
    "DEFAULTS",
    "PAIR_SUMS",
    "PRETENSION",
    "REFERENCES",
    "ControllerSettings",
    "CosimResult",
    "PlantFMU",
    "Reference",
    "controller_kind",
    "make_controller",
    "make_reference",
    "open_loop",
    "plot_tracking",
    "run",
]

FloatArray = NDArray[np.float64]

STEP = 0.03
INPUTS = ("T_cmd1", "T_cmd2", "T_cmd3", "T_cmd4")
OUTPUTS = ("q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z", "T1", "T2", "T3", "T4")
TRUTH = ("q1_true", "q2_true", "ee_x_true", "ee_y_true", "ee_z_true")
REFERENCES = ("petal", "circle", "step")
DEADLINE_S = 0.030
#: Pretension of the kinematic controller and of the pair-sum input target, N.


class Controller(Protocol):
    """What the master needs from a controller (``tendonkit.mpc`` controllers provide it)."""

    horizon: int

    def reset(self, u0: Any = None, y0: Any = None) -> None:
        """Start from input ``u0`` and measurement ``y0``."""

    def step(self, y_meas: Any, r_future: Any) -> Any:
        """One control step: returns an object with ``u``, ``fallback``, ``solve_time_s``."""


# -- references --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reference:
    """A reference for q1, q2 and the end effector, sampled every ``STEP`` seconds.

    Attributes
    ----------
    name : str
        ``petal``, ``circle`` or ``step``.
    t : array (n,)
        Sample times, s.
    q12 : array (n, 2)
        Joint references q1, q2, rad.
    ee : array (n, 3)
        End-effector reference, m.
    u_open_loop : array (n, 4)
        The open-loop kinematic controller's commands for this reference, N.
    info : dict
        The options the reference was built with.
    """

    name: str
    t: FloatArray
    q12: FloatArray
    ee: FloatArray
    u_open_loop: FloatArray
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def duration(self) -> float:
        """Length of the reference, s."""
        return len(self.t) * STEP

    def preview(self, k: int, horizon: int) -> FloatArray:
        """References for the next ``horizon`` samples after ``k`` (last value repeated)."""
        idx = np.minimum(np.arange(k + 1, k + 1 + horizon), len(self.t) - 1)
        return self.q12[idx]


def make_reference(
    kind: str,
    *,
    duration: float | None = None,
    amplitude: float = 0.09,
    petals: int = 3,
    speed: float = 0.025,
    laps: float | None = None,
) -> Reference:
    """Build a reference: ``petal``, ``circle`` or ``step`` (spec §12, MPC test reference).

    Petal and circle start with a 2 s ramp from the centre, run at the constant end-effector
    ``speed``, ramp back in 2 s and rest.  With ``duration`` and no ``laps`` they run as many
    laps as fit; the result is cut, or held at rest, to exactly ``duration``.

    Parameters
    ----------
    kind : str
        One of :data:`REFERENCES`.
    duration : float, optional
        Length, s (step: default 12 s).
    amplitude : float
        Petal amplitude A or circle radius, m (step: the joint step, rad, is 5/3 of it).
    petals : int
        The rose parameter k of the petal.
    speed : float
        End-effector speed, m/s.
    laps : float, optional
        Traversals of the curve (default: fill ``duration``, or 1 lap / 2 laps for a circle).

    Returns
    -------
    Reference

    Examples
    --------
    >>> make_reference("step", duration=3.0).q12.shape
    (100, 2)
    """

    problems = []
    if kind not in REFERENCES:
        problems.append(f"unknown reference {kind!r}; choose one of {', '.join(REFERENCES)}")
    if duration is not None and not (np.isfinite(duration) and STEP <= duration <= 3600):
        problems.append(f"duration must be in [{STEP}, 3600] s, found {duration!r}")
    if laps is not None and not (np.isfinite(laps) and 0 < laps <= 100):
        problems.append(f"laps must be in (0, 100], found {laps!r}")
    raise_if(problems, OptionError, "Invalid reference:")
    info = {"amplitude": amplitude, "petals": petals, "speed": speed, "laps": laps}
    try:
        if kind in ("petal", "circle"):

            def build(n_laps: float) -> Any:
                if kind == "petal":
                    return protocol.petal(petals, amplitude, speed=speed, laps=n_laps)
                return protocol.circles(radii=[amplitude], laps=n_laps, speed=speed)

            if laps is None and duration is not None:
                one = build(1.0)
                period = STEP * int(np.sum(one.phase == protocol.PHASES.index("main")))
                laps = max((duration - (one.n_samples * STEP - period)) / period, 0.05)
            p = build(laps if laps is not None else (1.0 if kind == "petal" else 2.0))
            info["laps"] = laps
            q12, ee, u = p.q_ref[:, :2], p.ee_ref, p.u
        else:
            n = round((duration or 12.0) / STEP)
            step = amplitude * 5.0 / 3.0
            q12 = np.zeros((n, 2))
            quarter = max(n // 4, 1)
            q12[quarter : 2 * quarter, 0] = step
            q12[2 * quarter : 3 * quarter, 1] = -step
            q12[3 * quarter :, :] = (2.0 * step / 3.0, 2.0 * step / 3.0)
            ee = forward_kinematics(expand_joints(q12))
            u = commanded_tensions(q12, PRETENSION)
    except OptionError as exc:
        raise OptionError("Invalid reference:", exc.problems or [str(exc)]) from None
    if duration is not None:
        n = round(duration / STEP)
        idx = np.minimum(np.arange(n), len(q12) - 1)  # cut, or hold the final rest
        q12, ee, u = q12[idx], ee[idx], u[idx]
    t = np.asarray(STEP * np.arange(len(q12)), dtype=np.float64)
    return Reference(
        kind, t, np.asarray(q12, float), np.asarray(ee, float), np.asarray(u, float), info
    )


# -- results -----------------------------------------------------------------------------------


def _stats_ms(seconds: FloatArray) -> dict[str, float]:
    ms = 1e3 * np.asarray(seconds, dtype=float)
    return {
        "median": float(np.median(ms)),
        "p99": float(np.percentile(ms, 99)),
        "max": float(np.max(ms)),
    }


def _rms(e: FloatArray) -> dict[str, float]:
    r = np.sqrt(np.mean(np.asarray(e) ** 2, axis=0))
    return {"q1": float(r[0]), "q2": float(r[1])}


@dataclass
class CosimResult:
    """Time series and summary figures of one closed-loop (or open-loop) run.

    Attributes
    ----------
    controller : str
        Name of the run.
    reference : Reference
        What was tracked.
    y : array (n, 13)
        Measured :data:`OUTPUTS` read at each step, before the command.
    truth : array (n, 5)
        :data:`TRUTH` at the same instants (the plant's true q1, q2 and end effector).
    u : array (n, 4)
        Applied commands, N.
    solve_times, step_times : array (n,)
        QP solve time and the controller's whole step (master-measured), s; empty open loop.
    fallbacks, violations : int
        Steps that held the previous input, and commands outside the bounds (clipped).
    wall_time_s, cpu_time_s, plant_time_s : float
        Wall-clock and process CPU time of the loop, and the wall time inside the plant FMU.
    statuses : dict
        Solver status -> count.
    parameters : dict
        The plant FMU's parameters in force.
    """

    controller: str
    reference: Reference
    y: FloatArray
    truth: FloatArray
    u: FloatArray
    solve_times: FloatArray
    step_times: FloatArray
    fallbacks: int
    violations: int
    wall_time_s: float
    statuses: dict[str, int] = field(default_factory=dict)
    cpu_time_s: float = 0.0
    plant_time_s: float = 0.0
    parameters: dict[str, Any] = field(default_factory=dict)

    @property
    def rms_error_true(self) -> FloatArray:
        """RMS of (true q1, q2 − reference), rad."""
        return np.sqrt(np.mean((self.truth[:, :2] - self.reference.q12) ** 2, axis=0))

    def summary(self) -> dict[str, Any]:
        """The figures the ``mpc`` command reports (JSON-ready).

        Errors are RMS over the whole run (ramps and rest included): ``rms_error_rad`` of the
        measured angles (camera noise and lag included, as the paper measures),
        ``rms_error_true_rad`` of the plant's true angles; the end-effector error is the mean
        distance to the reference, measured and true.  Times: the QP solve, the controller's
        whole step (estimation, linearisation, solve; a step above 30 ms misses its deadline)
        and the real-time factor (simulated time / wall time of the loop).
        """
        r = self.reference
        ee_err = np.linalg.norm(self.y[:, 6:9] - r.ee, axis=1)
        ee_true = np.linalg.norm(self.truth[:, 2:5] - r.ee, axis=1)
        out: dict[str, Any] = {
            "controller": self.controller,
            "reference": r.name,
            "duration_s": r.duration,
            "samples": len(r.t),
            "rms_error_rad": _rms(self.y[:, :2] - r.q12),
            "rms_error_true_rad": _rms(self.truth[:, :2] - r.q12),
            "mean_ee_error_cm": float(100 * np.mean(ee_err)),
            "mean_ee_error_true_cm": float(100 * np.mean(ee_true)),
            "fallbacks": int(self.fallbacks),
            "input_bound_violations": int(self.violations),
            "statuses": dict(self.statuses),
            "wall_time_s": self.wall_time_s,
            "cpu_time_s": self.cpu_time_s,
            "plant_time_s": self.plant_time_s,
            "realtime_factor": r.duration / self.wall_time_s if self.wall_time_s > 0 else None,
        }
        if len(self.solve_times):
            out["solve_time_ms"] = _stats_ms(self.solve_times)
            out["step_time_ms"] = _stats_ms(self.step_times)
            out["deadline_misses"] = int(np.sum(self.step_times > DEADLINE_S))
        return out


# -- the plant ---------------------------------------------------------------------------------


class PlantFMU:
    """A plant FMU instance, stepped frame by frame (a view of :data:`OUTPUTS` + :data:`TRUTH`).

    Parameters
    ----------
    path : str or Path
        A tendonkit plant FMU.
    parameters : mapping, optional
        Parameter overrides by FMU name (``friction_on``, ``delay_s`` …).
    """

    def __init__(self, path: str | Path, parameters: Mapping[str, Any] | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise FMUError(f"Plant FMU {str(path)!r} does not exist.")
        self._session = PlantSession(path, parameters)
        self._index = np.array([ALL.index(n) for n in (*OUTPUTS, *TRUTH)])
        self.parameters = dict(self._session.parameters)

    def start(self) -> FloatArray:
        """The outputs at t = 0 (the FMU is initialised on construction)."""
        return self._session.outputs[self._index]

    def step(self, u: FloatArray) -> FloatArray:
        """Apply ``u`` over one 30 ms step; returns the outputs at the end of it."""
        return self._session.step(u)[self._index]

    def close(self) -> None:
        """Terminate and free the instance."""
        self._session.close()


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

    The controller measures the plant outputs named like its model's outputs (``q1``, ``q2``)
    and gets the reference preview in that order; its inputs are the commanded forces
    ``T_cmd1..T_cmd4`` in order.

    Parameters
    ----------
    plant_fmu : str or Path
        The plant FMU.
    reference : Reference
        What to track (:func:`make_reference`).
    controller : Controller, optional
        E.g. from :func:`make_controller`; None runs the open-loop kinematic controller.
    parameters : mapping, optional
        Plant FMU parameter overrides.
    u_min, u_max : float
        Input bounds, N: commands outside are clipped and counted as violations.
    name : str
        Name of the run in the result.
    progress : bool
        Show a progress bar on standard error.

    Returns
    -------
    CosimResult
    """
    # lazy: heavy (tqdm)
    from tqdm import tqdm

    names = list(getattr(controller, "output_names", ["q1", "q2"])) if controller else []
    if any(n not in ("q1", "q2") for n in names):
        raise OptionError(f"Only q1 and q2 have a reference; the controller measures {names}.")
    meas = np.array([OUTPUTS.index(n) for n in names], dtype=int)
    ref_cols = np.array([("q1", "q2").index(n) for n in names], dtype=int)
    n = len(reference.t)
    Y = np.empty((n, len(OUTPUTS) + len(TRUTH)))
    U = np.empty((n, 4))
    solve = np.zeros(n if controller is not None else 0)
    steps = np.zeros_like(solve)
    fallbacks = violations = 0
    statuses: dict[str, int] = {}
    u_prev = reference.u_open_loop[0].copy()
    plant = PlantFMU(plant_fmu, parameters)
    plant_time = 0.0
    clock, cpu = time.perf_counter, time.process_time
    try:
        y = plant.start()
        if controller is not None:
            controller.reset(u0=u_prev, y0=y[meas])
        t0, c0 = clock(), cpu()
        for k in tqdm(range(n), desc=name, disable=not progress, unit="step", leave=False):
            Y[k] = y
            if controller is None:
                u = reference.u_open_loop[k]
            else:
                ts = clock()
                res = controller.step(
                    y[meas], reference.preview(k, controller.horizon)[:, ref_cols]
                )
                steps[k] = clock() - ts
                u = np.asarray(res.u, dtype=float)
                fallbacks += int(bool(res.fallback))
                solve[k] = float(res.solve_time_s)
                statuses[str(res.status)] = statuses.get(str(res.status), 0) + 1
            if not (np.all(np.isfinite(u)) and np.all(u >= u_min) and np.all(u <= u_max)):
                violations += 1
                u = np.clip(np.where(np.isfinite(u), u, u_prev), u_min, u_max)
            U[k] = u
            u_prev = u
            tp = clock()
            y = plant.step(u)
            plant_time += clock() - tp
        wall, cpu_time = clock() - t0, cpu() - c0
        params = plant.parameters
    finally:
        plant.close()
    return CosimResult(
        controller=name,
        reference=reference,
        y=Y[:, : len(OUTPUTS)],
        truth=Y[:, len(OUTPUTS) :],
        u=U,
        solve_times=solve,
        step_times=steps,
        fallbacks=fallbacks,
        violations=violations,
        wall_time_s=wall,
        statuses=statuses,
        cpu_time_s=cpu_time,
        plant_time_s=plant_time,
        parameters=params,
    )


def open_loop(plant_fmu: str | Path, reference: Reference, **kwargs: Any) -> CosimResult:
    """The open-loop kinematic controller of the data-collection protocol on the same plant.

    Parameters
    ----------
    plant_fmu : str or Path
        The plant FMU.
    reference : Reference
        Its ``u_open_loop`` commands are played.
    **kwargs
        As for :func:`run` (``parameters``, ``progress``).

    Returns
    -------
    CosimResult
    """
    return run(plant_fmu, reference, None, name="open-loop kinematic", **kwargs)
