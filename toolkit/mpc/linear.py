"""Prediction models of the linear MPC: realisation, reduction, disturbance model, Kalman gain.

Any linear tendonkit model (``state_space``; ``arx`` with or without an ``offset``; input
``delay``, ``first_order_lag`` and ``second_order_section`` blocks, realised as states) becomes ``x+ = A x + B u``, ``y = C x + D u + y_const`` through
:func:`tendonkit.realize.to_state_space`.  A non-minimal realisation (an ARX(8, 8) model with
4 inputs and 2 outputs realises to 48 states, of which 16 are needed) is reduced exactly with
python-control's ``minreal`` (slycot ``tb01pd``), or by balanced truncation to a given order.
A model's innovation gain ``K`` is carried through the reduction as extra input columns.

For offset-free tracking the state is augmented with integrating disturbances ``d``::

    x+ = A x + B u + Bd d,   d+ = d,   y = C x + D u + Cd d + y_const

(``output``: ``Bd = 0, Cd = I``; ``input``: ``Bd = B G0⁺, Cd = D G0⁺`` with ``G0`` the static
gain, so that ``d`` is an input disturbance expressed in output units at steady state), and
estimated with the steady-state Kalman predictor of the augmented system.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import OptionError
from ..realize import to_state_space
from ..schema import ARX, LINEAR_BLOCKS, Model, StateSpace
from .base import _MPC, _formulation
from .options import Bounds, Estimator, Solver, Weights, resolve_options
from .qp import QPResult, TrackingQP

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LinearPrediction:
    """A linear prediction model ``x+ = Ax + Bu``, ``y = Cx + Du + y_const`` for the MPC.

    ``K`` is the model's innovation gain in the same coordinates (``None`` if it has none);
    ``n_realized`` is the order of the exact realisation before any reduction.
    """

    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    K: FloatArray | None
    y_const: FloatArray
    n_realized: int

    @property
    def n_states(self) -> int:
        """Order of the prediction model."""
        return int(self.A.shape[0])


def linear_problems(model: Model) -> list[str]:
    """Reasons why ``model`` cannot be controlled by the linear MPC (empty when it can)."""
    problems = []
    rep = model.representation
    if rep.kind == "sparse_map":
        problems.append(
            f"model {model.name!r} is a sparse_map (nonlinear); use NonlinearMPC for it."
        )
    if isinstance(rep, ARX) and rep.terms:
        problems.append(f"ARX model {model.name!r} has nonlinear terms; the linear MPC needs none.")
    for b in model.input_blocks:
        if b.kind not in LINEAR_BLOCKS:
            problems.append(
                f"input block {b.kind!r} on {b.signal!r} is nonlinear; only 'delay', "
                "'first_order_lag' and 'second_order_section' input blocks are linear."
            )
    for b in model.output_blocks:
        problems.append(f"output block {b.kind!r} on {b.signal!r} is not supported by the MPC.")
    return problems


def prediction_model(model: Model, reduce: str | int = "minreal") -> LinearPrediction:
    """The (reduced) state-space prediction model of a linear ``model``.

    Parameters
    ----------
    model : Model
        A linear model (see :func:`linear_problems`).
    reduce : "minreal", "none" or int
        ``"minreal"`` removes uncontrollable/unobservable states (exact); an integer is the
        order of a balanced truncation (stable models only); ``"none"`` keeps the realisation.
    """
    rep = model.representation
    ny = len(model.outputs)
    y_const = np.zeros(ny)
    if isinstance(rep, ARX) and rep.offset is not None and np.any(rep.offset != 0):
        # A(q) y = B(q) u + c: the offset adds the constant A(1)^-1 c to the outputs.
        a1 = np.eye(ny) + sum((a for a in rep.A), np.zeros((ny, ny)))
        try:
            y_const = np.asarray(np.linalg.solve(a1, rep.offset), dtype=np.float64)
        except np.linalg.LinAlgError:
            raise OptionError(
                f"ARX model {model.name!r} has an offset and an integrator (A(1) is singular); "
                "its offset cannot be folded into a constant output offset."
            ) from None
        model = model.replace(representation=replace(rep, offset=None))
    if isinstance(rep, StateSpace) and rep.has_offsets:
        # y = G(q)(u - u0) + y0: a stable model adds the constant y0 - G(1) u0 to the outputs.
        n = rep.n_states
        u0, y0 = rep.operating_point
        y_const = y0.copy()
        if np.any(u0 != 0):
            try:
                gain = rep.C @ np.linalg.solve(np.eye(n) - rep.A, rep.B) + rep.D
            except np.linalg.LinAlgError:
                raise OptionError(
                    f"State-space model {model.name!r} has an input offset and an integrator "
                    "(I - A is singular); its offset cannot be folded into a constant output "
                    "offset."
                ) from None
            y_const = y_const - gain @ u0
        model = model.replace(representation=replace(rep, u0=None, y0=None))
    ss = to_state_space(model)
    A, B, C, D = (np.asarray(m, dtype=float) for m in (ss.A, ss.B, ss.C, ss.D))
    K = None if not isinstance(rep, StateSpace) or ss.K is None else np.asarray(ss.K, float)
    n0 = A.shape[0]
    if reduce == "none" or n0 == 0:
        return LinearPrediction(A, B, C, D, K, y_const, n0)
    nu = B.shape[1]
    Bk = B if K is None else np.hstack([B, K])
    Dk = D if K is None else np.hstack([D, np.zeros((ny, ny))])
    Ar, Bkr, Cr, Dkr = _reduce(A, Bk, C, Dk, model.dt, reduce)
    Kr = None if K is None else Bkr[:, nu:]
    return LinearPrediction(Ar, Bkr[:, :nu], Cr, Dkr[:, :nu], Kr, y_const, n0)


def _reduce(
    A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray, dt: float, reduce: str | int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Minimal realisation (python-control/slycot TB01PD) or balanced truncation (AB09AD)."""
    if reduce == "minreal":
        # lazy: heavy (control)
        import control

        red = control.minreal(control.ss(A, B, C, D, dt), verbose=False)
        mats = (red.A, red.B, red.C, red.D)
        return tuple(np.atleast_2d(np.asarray(m, dtype=float)) for m in mats)  # type: ignore[return-value]
    order = int(reduce)
    if order >= A.shape[0]:
        return A, B, C, D
    if np.max(np.abs(np.linalg.eigvals(A))) >= 1.0:
        raise OptionError(
            f"Balanced truncation to order {order} needs a stable model; this one has a pole "
            "on or outside the unit circle. Use reduce='minreal' or 'none'."
        )
    # python-control 0.10's balred() treats every system as continuous-time (it would keep
    # every mode with a positive real part), so call slycot's discrete-time AB09AD directly.
    # lazy: heavy (slycot)
    from slycot import ab09ad

    n, m, p = A.shape[0], B.shape[1], C.shape[0]
    nr, Ar, Br, Cr, _ = ab09ad("D", "B", "N", n, m, p, A, B, C, nr=order, tol=0.0)
    return (
        np.asarray(Ar[:nr, :nr], dtype=float),
        np.asarray(Br[:nr], dtype=float),
        np.asarray(Cr[:, :nr], dtype=float),
        D,
    )


def disturbance_matrices(lp: LinearPrediction, kind: str) -> tuple[FloatArray, FloatArray]:
    """``(Bd, Cd)`` of the integrating disturbance model ``kind`` (output, input or none)."""
    n, ny = lp.n_states, lp.C.shape[0]
    if kind == "none":
        return np.zeros((n, 0)), np.zeros((ny, 0))
    if kind == "output":
        return np.zeros((n, ny)), np.eye(ny)
    G0 = static_gain(lp)
    if np.linalg.matrix_rank(G0) < ny:
        raise OptionError(
            "disturbance='input' needs a static gain of full row rank (every output reachable "
            f"at steady state); this model's has rank {np.linalg.matrix_rank(G0)} < {ny}. "
            "Use disturbance='output'."
        )
    M = np.linalg.pinv(G0)
    return lp.B @ M, lp.D @ M


def static_gain(lp: LinearPrediction) -> FloatArray:
    """Steady-state gain ``C (I - A)^-1 B + D`` (least squares for an integrating model)."""
    n = lp.n_states
    X = np.linalg.lstsq(np.eye(n) - lp.A, lp.B, rcond=None)[0]
    return np.asarray(lp.C @ X + lp.D)


def predictor_gain(
    lp: LinearPrediction,
    Bd: FloatArray,
    Cd: FloatArray,
    process: float,
    measurement: float,
    disturbance: float,
) -> FloatArray:
    """Steady-state Kalman predictor gain of the disturbance-augmented model.

    Noise: white measurement noise of covariance ``measurement·I`` and a random walk of
    covariance ``disturbance·I`` on ``d``.  The state noise is ``K e`` when the model has an
    innovation gain ``K`` (so that without disturbances the gain is exactly ``K``), otherwise
    white with covariance ``process·I``.

    Returns
    -------
    array (n + nd, ny)
        Gain ``L`` of ``x̂a[k+1] = Aa x̂a[k] + Ba u[k] + L (y[k] - ŷ[k])``.
    """
    # lazy: heavy (scipy)
    from scipy.linalg import solve_discrete_are

    n, nd, ny = lp.n_states, Bd.shape[1], lp.C.shape[0]
    Aa = np.block([[lp.A, Bd], [np.zeros((nd, n)), np.eye(nd)]])
    Ca = np.hstack([lp.C, Cd])
    R = measurement * np.eye(ny)
    Qa = np.zeros((n + nd, n + nd))
    S = np.zeros((n + nd, ny))
    if lp.K is not None:
        Qa[:n, :n] = lp.K @ R @ lp.K.T
        S[:n] = lp.K @ R
    else:
        Qa[:n, :n] = process * np.eye(n)
    Qa[n:, n:] = disturbance * np.eye(nd)
    try:
        P = solve_discrete_are(Aa.T, Ca.T, Qa, R, s=S)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise OptionError(
            "No steady-state Kalman gain for the disturbance-augmented model "
            f"({exc}). An integrating model cannot take disturbance='output'; try "
            "disturbance='input' or 'none'."
        ) from None
    return np.asarray((Aa @ P @ Ca.T + S) @ np.linalg.inv(Ca @ P @ Ca.T + R))


class LinearMPC(_MPC):
    """Offset-free linear MPC for a linear model (``state_space``, ``arx``, input delays and
    first-order lags).

    Parameters
    ----------
    model : Model
        A linear model; its inputs are the manipulated variables, its outputs the controlled
        and measured ones.
    horizon : int
        Prediction and control horizon N (samples).
    weights : Weights, optional
        Output tracking weights ``Q``/``Qf`` (default identity), input-move weight ``R``
        (default 0.1·I), output-bound slack penalty, optional :class:`InputTarget`.
    bounds : Bounds, optional
        Hard input bounds (default 20..190 N), soft output bounds (default ±1 rad; ``±inf``
        removes one), input-move bound.
    estimator : Estimator, optional
        Integrating disturbance model (``"output"``, ``"input"`` or ``"none"``) and the Kalman
        predictor's :class:`NoiseCovariance`.
    solver : Solver, optional
        QP solver (``"clarabel"`` or ``"osqp"``), the direct path (``fast``), solver options,
        ``formulation`` (``"auto"``, ``"sparse"`` keeps the predicted states as variables,
        ``"condensed"`` eliminates them; ``auto`` picks sparse for Clarabel and condensed for
        OSQP, the faster pairs in ``benchmarks/bench_mpc_solvers.py``) and a test
        ``failure_hook(step) -> bool`` making that step behave as a solver failure.
    reduce : "minreal", "none" or int
        Reduction of the realisation: exact minimal realisation, none, or balanced truncation
        to the given order.
    **legacy
        The keywords of tendonkit 0.1 (``Q``, ``u_min``, ``solver="osqp"``, ...): mapped onto
        the option objects with a ``DeprecationWarning``, until the next release.

    Attributes
    ----------
    prediction : LinearPrediction
        The (reduced) prediction model; ``prediction.n_realized`` is the order before
        reduction.
    n_steps, n_fallbacks : int
        Steps since :meth:`reset`, and how many of them held the previous input.

    Examples
    --------
    >>> from tendonkit.testsystems import random_state_space
    >>> from tendonkit.mpc import Bounds
    >>> mpc = LinearMPC(random_state_space(4, 2, 2), horizon=5, bounds=Bounds(u_min=-1, u_max=1))
    >>> mpc.n_states, mpc.problem.is_dpp()
    (4, True)
    """

    _disturbances = ("output", "input", "none")

    def __init__(
        self,
        model: Model,
        *,
        horizon: int = 20,
        weights: Weights | None = None,
        bounds: Bounds | None = None,
        estimator: Estimator | None = None,
        solver: Solver | None = None,
        reduce: str | int = "minreal",
        **legacy: Any,
    ) -> None:
        opts = resolve_options(
            "LinearMPC",
            {"weights": weights, "bounds": bounds, "estimator": estimator, "solver": solver},
            legacy,
        )
        formulation = opts["solver"].formulation
        problems = linear_problems(model)
        if not (
            reduce in ("minreal", "none")
            or (isinstance(reduce, int) and not isinstance(reduce, bool) and reduce >= 1)
        ):
            problems.append(f"reduce must be 'minreal', 'none' or an order >= 1, found {reduce!r}.")
        if formulation not in ("auto", "sparse", "condensed"):
            problems.append(
                f"formulation must be 'auto', 'sparse' or 'condensed', found {formulation!r}."
            )
        super().__init__(model, horizon=horizon, model_problems=problems, **opts)
        lp = prediction_model(model, reduce)
        self.prediction = lp
        self._Bd, self._Cd = disturbance_matrices(lp, self.disturbance)
        nz = self.noise
        self._L = predictor_gain(lp, self._Bd, self._Cd, nz.process, nz.measurement, nz.disturbance)
        self._qp = TrackingQP(
            self._spec(lp.n_states, lp.A, lp.B, lp.C, lp.D),
            solver=self.solver,
            fast=self.fast,
            solver_options=self.solver_options,
            formulation=_formulation(formulation, self.solver),
        )
        n, nd = lp.n_states, self._Bd.shape[1]
        self._x = np.zeros(n)
        self._d = np.zeros(nd)
        self._x1 = np.zeros(n)
        self._d_next = np.zeros(nd)

    @property
    def n_states(self) -> int:
        """Order of the (reduced) prediction model."""
        return self.prediction.n_states

    @property
    def disturbance_estimate(self) -> FloatArray:
        """Current estimate of the integrating disturbances (output units)."""
        return self._d.copy()

    def _reset_state(self, u: FloatArray, y: FloatArray | None) -> None:
        lp, n = self.prediction, self.prediction.n_states
        d: FloatArray = np.zeros(self._Bd.shape[1])
        if y is not None and d.size:
            # Either disturbance model has unit static gain from d to y (input: G0 G0⁺ = I),
            # so d explains the whole difference between measured and modelled outputs.
            d = np.asarray(y - (static_gain(lp) @ u + lp.y_const), dtype=float)
        rhs = lp.B @ u + self._Bd @ d
        self._x = np.asarray(np.linalg.lstsq(np.eye(n) - lp.A, rhs, rcond=None)[0], dtype=float)
        self._d = d

    def _observe(self, y: FloatArray | None) -> None:
        lp, n = self.prediction, self.prediction.n_states
        x, d = self._x, self._d
        y_hat = lp.C @ x + lp.D @ self._u_prev + self._Cd @ d + lp.y_const
        e = np.zeros_like(y_hat) if y is None else y - y_hat
        corr = self._L @ e
        self._x1 = lp.A @ x + self._Bd @ d + corr[:n]
        self._d_next = d + corr[n:]

    def _qp_values(self, r: FloatArray) -> dict[str, Any]:
        lp = self.prediction
        return {
            "x1": self._x1,
            "w": self._Bd @ self._d_next,
            "yoff": self._Cd @ self._d_next + lp.y_const,
            "r": r,
            "u_prev": self._u_prev,
        }

    def _advance(self, u: FloatArray, res: QPResult | None) -> None:
        self._x = self._x1 + self.prediction.B @ u
        self._d = self._d_next
