"""Common part of the MPC controllers: options, measurements, references, fallback, clipping.

The public names are re-exported by :mod:`tendonkit.mpc`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DataError, OptionError, raise_if
from ..schema import Model
from .options import Bounds, Estimator, Solver, Weights
from .qp import SOLVERS, QPResult, QPSpec, TrackingQP

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class StepResult:
    """What one controller step produced.

    Attributes
    ----------
    u : array (nu,)
        The input to apply, in the order of the model's inputs, always within the bounds.
    status : str
        Solver status (``"Solved"``, ``"optimal"``, ``"solved"``), or why the step fell back.
    solve_time_s : float
        Time to set the QP parameters and solve it (seconds).
    fallback : bool
        True when the previous input was held because no usable solution was found.
    predicted_y : array (N, ny) or None
        Predicted outputs ``y_1..y_N`` of the plan (None on fallback).
    step_time_s : float
        Time of the whole step: estimation, linearisation and solve (seconds).
    input_names : tuple of str
        Names of the entries of ``u``.
    """

    u: FloatArray
    status: str
    solve_time_s: float
    fallback: bool
    predicted_y: FloatArray | None
    step_time_s: float = 0.0
    input_names: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, float]:
        """The input as a mapping ``name -> value`` (for a plant with more inputs)."""
        return {name: float(v) for name, v in zip(self.input_names, self.u)}


@dataclass(frozen=True)
class NoiseCovariance:
    """Noise covariances (times identity) of the state estimator.

    Parameters
    ----------
    process : float
        Process noise on the model state (ignored by :class:`LinearMPC` when the model has an
        innovation gain ``K``, which then defines the state noise).
    measurement : float
        Output measurement noise (rad²).
    disturbance : float
        Random-walk covariance of the integrating disturbances; larger values remove a
        model/plant mismatch faster but pass more noise.
    """

    process: float = 1e-4
    measurement: float = 1e-4
    disturbance: float = 1e-4

    def __post_init__(self) -> None:
        bad = [
            f"{k} must be a finite number > 0, found {getattr(self, k)!r}."
            for k in ("process", "measurement", "disturbance")
            if not (np.isfinite(getattr(self, k)) and getattr(self, k) > 0)
        ]
        raise_if(bad, OptionError, "Invalid noise covariances:")


@dataclass(frozen=True)
class InputTarget:
    """A penalty ``Σ_j |u_j - value|²_weight`` that holds inputs the outputs leave free.

    With more inputs than outputs (four tendons, two joint angles) the tracking cost does not
    fix every input combination: the common mode of an antagonistic pair changes the stiffness,
    not the angle.  A model that is wrong along such a direction lets the optimiser drift along
    it (for example down to slack tendons).  A small weight on ``M (u - value)``, with ``M``
    selecting the free directions, anchors them without biasing the tracked outputs.

    Parameters
    ----------
    weight : float, array (nu,) or (nu, nu)
        Positive semidefinite weight (per squared input unit, e.g. 1/N²).
    value : float or array (nu,)
        The target input.

    Examples
    --------
    >>> import numpy as np
    >>> M = np.array([[1.0, 0, 1, 0], [0, 1, 0, 1]])  # pair sums of two antagonistic pairs
    >>> InputTarget(weight=0.1 * M.T @ M, value=105.0).value
    105.0
    """

    weight: Any
    value: Any = 0.0


class _MPC:
    """Common part of the controllers: options, reference handling, fallback, clipping."""

    _disturbances: tuple[str, ...] = ("output", "none")

    def __init__(
        self,
        model: Model,
        *,
        horizon: int,
        weights: Weights,
        bounds: Bounds,
        estimator: Estimator,
        solver: Solver,
        model_problems: list[str],
    ) -> None:
        Q, R, Qf = weights.Q, weights.R, weights.Qf
        slack_weight, input_target = weights.slack, weights.input_target
        u_min, u_max, y_min, y_max, du_max = (
            bounds.u_min, bounds.u_max, bounds.y_min, bounds.y_max, bounds.du_max
        )  # fmt: skip
        disturbance, noise = estimator.disturbance, estimator.noise
        solver_options, failure_hook, fast = solver.options, solver.failure_hook, solver.fast
        self.options = {"weights": weights, "bounds": bounds, "estimator": estimator}
        self.options["solver"] = solver
        solver_name = solver.name
        nu, ny = len(model.inputs), len(model.outputs)
        p = list(model_problems)
        if isinstance(horizon, bool) or not isinstance(horizon, int | np.integer) or horizon < 1:
            p.append(f"horizon must be an integer >= 1, found {horizon!r}.")
            horizon = 1
        self._Q = _weight(Q, ny, "Q", p)
        self._R = _weight(0.1 if R is None else R, nu, "R", p)
        self._Qf = _weight(Qf, ny, "Qf", p)
        self._S: FloatArray | None = None
        self._u_target = np.zeros(nu)
        if input_target is not None and not isinstance(input_target, InputTarget):
            p.append(f"input_target must be an InputTarget, found {type(input_target).__name__}.")
        elif input_target is not None:
            self._S = _weight(input_target.weight, nu, "input_target.weight", p)
            self._u_target = _vector(input_target.value, nu, "input_target.value", p)
            if not np.all(np.isfinite(self._u_target)):
                p.append("input_target.value must be finite.")
        self.u_min = _vector(u_min, nu, "u_min", p)
        self.u_max = _vector(u_max, nu, "u_max", p)
        self.du_max = _vector(du_max, nu, "du_max", p)
        if np.any(np.isnan(self.du_max)) or np.any(self.du_max <= 0):
            p.append(f"du_max must be > 0 (inf for no limit), found {du_max!r}.")
        self.y_min = _vector(y_min, ny, "y_min", p)
        self.y_max = _vector(y_max, ny, "y_max", p)
        for lo, hi, what in ((self.u_min, self.u_max, "u"), (self.y_min, self.y_max, "y")):
            if lo.shape == hi.shape and np.any(lo >= hi):
                p.append(f"{what}_min must be below {what}_max for every signal.")
        if np.any(np.isnan(self.u_min)) or np.any(np.isnan(self.u_max)):
            p.append("input bounds must not be NaN.")
        sw = _slack_weight(slack_weight, p)
        if disturbance not in self._disturbances:
            p.append(
                f"disturbance must be one of {list(self._disturbances)}, found {disturbance!r}."
            )
        if solver_name not in SOLVERS:
            p.append(f"solver must be one of {list(SOLVERS)}, found {solver_name!r}.")
        if noise is not None and not isinstance(noise, NoiseCovariance):
            p.append(f"noise must be a NoiseCovariance, found {type(noise).__name__}.")
        raise_if(p, OptionError, f"Cannot build an MPC controller for model {model.name!r}:")
        self.model = model
        self.horizon = int(horizon)
        self.slack_weight = sw
        self.disturbance = disturbance
        self.noise = noise or NoiseCovariance()
        self.solver = solver_name
        self.fast = bool(fast)
        self.solver_options = dict(solver_options or {})
        self.failure_hook = failure_hook
        finite = np.isfinite(self.u_min) & np.isfinite(self.u_max)
        self._u_center = np.where(finite, 0.5 * (self.u_min + self.u_max), 0.0)
        self._u_scale = np.where(finite, 0.5 * (self.u_max - self.u_min), 1.0)
        self._u_prev = np.clip(self._u_center, self.u_min, self.u_max)
        self._started = False
        self.n_steps = 0
        self.n_fallbacks = 0
        self._qp: TrackingQP

    # -- public --------------------------------------------------------------------------
    @property
    def input_names(self) -> list[str]:
        """The model's input names: the order of ``StepResult.u``."""
        return self.model.input_names

    @property
    def output_names(self) -> list[str]:
        """The model's output names: the order of measurements and references."""
        return self.model.output_names

    @property
    def problem(self) -> Any:
        """The cvxpy ``Problem`` (parameters: x1, w, yoff, r, u_prev, and A_j, B_j)."""
        return self._qp.problem

    def reset(self, u0: ArrayLike | None = None, y0: ArrayLike | None = None) -> None:
        """Start a new run: previous input ``u0`` and, if known, the measured outputs ``y0``.

        Parameters
        ----------
        u0 : array (nu,), optional
            Input applied before the first step (default: middle of the bounds); clipped.
        y0 : array (ny,) or mapping, optional
            Outputs measured at that input; the estimator starts at the matching steady state
            (with a disturbance estimate explaining any difference).
        """
        nu = len(self.model.inputs)
        u = self._u_center if u0 is None else np.asarray(u0, dtype=float).reshape(-1)
        if u.shape != (nu,) or not np.all(np.isfinite(u)):
            raise DataError(f"u0 must be {nu} finite numbers for {self.input_names}, found {u0!r}.")
        u = np.clip(u, self.u_min, self.u_max)
        y = None if y0 is None else self._measurement(y0)
        if y is not None and not np.all(np.isfinite(y)):
            y = None
        self._u_prev = u
        self._reset_state(u, y)
        self._started = True
        self.n_steps = 0
        self.n_fallbacks = 0

    def step(self, y_meas: ArrayLike | Mapping[str, float], r_future: ArrayLike) -> StepResult:
        """Measure, estimate, solve and return the input for this sample.

        Parameters
        ----------
        y_meas : array (ny,) or mapping name -> value
            Measured outputs (a mapping may hold more signals; the model's outputs are taken).
            Non-finite values skip the measurement update and hold the input.
        r_future : array (n, ny) or (ny,)
            Reference preview for ``y_1..y_N``; padded with its last row, or truncated, to N.

        Returns
        -------
        StepResult
        """
        t0 = time.perf_counter()
        y = self._measurement(y_meas)
        r = self._reference(r_future)
        valid = bool(np.all(np.isfinite(y)))
        if not self._started:
            self.reset(self._u_prev, y if valid else None)
        k = self.n_steps
        self.n_steps += 1
        self._observe(y if valid else None)
        status, res, solve_time = "invalid measurement", None, 0.0
        if valid and self.failure_hook is not None and self.failure_hook(k):
            status = "forced failure"
        elif valid:
            try:
                values = self._qp_values(r)
            except _LinearizationError as exc:
                status = f"linearization failed: {exc}"
            else:
                t1 = time.perf_counter()
                try:
                    self._qp.set_parameters(**values)
                    res = self._qp.solve()
                    status = res.status
                # The control loop must go on: any solver failure becomes a fallback.
                except Exception as exc:
                    status = f"solver error: {type(exc).__name__}: {exc}"
                solve_time = time.perf_counter() - t1
        ok = res is not None and res.ok and res.U is not None
        if ok:
            assert res is not None and res.U is not None and res.Y is not None
            u = np.clip(res.U[:, 0], self.u_min, self.u_max)
            predicted: FloatArray | None = res.Y.T.copy()
        else:
            u = self._u_prev.copy()
            predicted = None
            self.n_fallbacks += 1
        self._advance(u, res if ok else None)
        self._u_prev = u
        return StepResult(
            u=u,
            status=status,
            solve_time_s=solve_time,
            fallback=not ok,
            predicted_y=predicted,
            step_time_s=time.perf_counter() - t0,
            input_names=tuple(self.input_names),
        )

    # -- helpers -------------------------------------------------------------------------
    def _spec(
        self, n: int, A: FloatArray | None, B: FloatArray | None, C: FloatArray, D: FloatArray
    ) -> QPSpec:
        return QPSpec(
            n=n,
            nu=len(self.model.inputs),
            ny=len(self.model.outputs),
            horizon=self.horizon,
            A=A,
            B=B,
            C=C,
            D=D,
            Lq=_sqrt_psd(self._Q),
            Lqf=_sqrt_psd(self._Qf),
            Lr=_sqrt_psd(self._R),
            u_min=self.u_min,
            u_max=self.u_max,
            u_center=self._u_center,
            u_scale=self._u_scale,
            y_min=self.y_min,
            y_max=self.y_max,
            slack_weight=self.slack_weight,
            Ls=None if self._S is None else _sqrt_psd(self._S),
            u_target=self._u_target,
            du_max=self.du_max,
        )

    def _measurement(self, y: ArrayLike | Mapping[str, float]) -> FloatArray:
        names = self.output_names
        if isinstance(y, Mapping):
            missing = [n for n in names if n not in y]
            if missing:
                raise DataError(
                    f"The measurement lacks outputs {missing} of model {self.model.name!r}; "
                    f"found {sorted(y)}."
                )
            return np.array([float(y[n]) for n in names])
        arr = np.asarray(y, dtype=float).reshape(-1)
        if arr.shape != (len(names),):
            raise DataError(
                f"The measurement must hold {len(names)} values for {names}, found shape {np.shape(y)}."
            )
        return arr

    def _reference(self, r: ArrayLike) -> FloatArray:
        ny, N = len(self.model.outputs), self.horizon
        arr = np.asarray(r, dtype=float)
        if arr.ndim == 1 and arr.shape == (ny,):
            arr = arr[None, :]
        elif arr.ndim == 1 and ny == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != ny or arr.shape[0] == 0 or not np.all(np.isfinite(arr)):
            raise DataError(
                f"The reference must be finite with shape (n, {ny}) for {self.output_names}, "
                f"found shape {np.shape(r)}."
            )
        if arr.shape[0] >= N:
            return arr[:N]
        return np.vstack([arr, np.repeat(arr[-1:], N - arr.shape[0], axis=0)])

    # -- subclass hooks ------------------------------------------------------------------
    def _reset_state(self, u: FloatArray, y: FloatArray | None) -> None:  # pragma: no cover
        raise NotImplementedError

    def _observe(self, y: FloatArray | None) -> None:  # pragma: no cover
        raise NotImplementedError

    def _qp_values(self, r: FloatArray) -> dict[str, Any]:  # pragma: no cover
        raise NotImplementedError

    def _advance(self, u: FloatArray, res: QPResult | None) -> None:  # pragma: no cover
        raise NotImplementedError


class _LinearizationError(RuntimeError):
    """The nominal trajectory of the nonlinear model is not finite."""


# -- option helpers ------------------------------------------------------------------------------


def _formulation(choice: str, solver: str) -> str:
    """``auto``: states as variables for Clarabel (sparse KKT), eliminated for OSQP."""
    if choice != "auto":
        return choice
    return "sparse" if solver == "clarabel" else "condensed"


def _slack_weight(value: float | tuple[float, float], problems: list[str]) -> tuple[float, float]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size == 1:
        arr = np.repeat(arr, 2)
    if arr.size != 2 or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        problems.append(f"slack_weight must be a number > 0 or two of them, found {value!r}.")
        return (1.0, 1.0)
    return (float(arr[0]), float(arr[1]))


def _vector(value: ArrayLike, n: int, name: str, problems: list[str]) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        problems.append(f"{name} must be a number or {n} numbers, found shape {arr.shape}.")
        return np.zeros(n)
    return arr.copy()


def _weight(value: ArrayLike | None, n: int, name: str, problems: list[str]) -> FloatArray:
    if value is None:
        return np.eye(n)
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = float(arr) * np.eye(n)
    elif arr.ndim == 1 and arr.shape == (n,):
        arr = np.diag(arr)
    if arr.shape != (n, n) or not np.all(np.isfinite(arr)):
        problems.append(f"{name} must be a number, {n} numbers or a finite ({n}, {n}) matrix.")
        return np.eye(n)
    if not np.allclose(arr, arr.T) or np.min(np.linalg.eigvalsh(0.5 * (arr + arr.T))) < -1e-12:
        problems.append(f"{name} must be symmetric positive semidefinite.")
        return np.eye(n)
    return 0.5 * (arr + arr.T)


def _sqrt_psd(M: FloatArray) -> FloatArray:
    """A square root ``L`` with ``Lᵀ L = M`` (diagonal stays diagonal)."""
    if np.count_nonzero(M - np.diag(np.diag(M))) == 0:
        return np.diag(np.sqrt(np.maximum(np.diag(M), 0.0)))
    w, V = np.linalg.eigh(M)
    return np.asarray(np.diag(np.sqrt(np.maximum(w, 0.0))) @ V.T)
