"""The prediction form of :mod:`tendonkit.plugins.pem`: ``K`` and every other parameter refitted
by the k-step prediction error (MATLAB ``ssest(..., 'Focus', 'prediction')``).

The model is the innovation form around the operating point (``Δu = u - u0``, ``Δy = y - y0``)::

    x[t+1] = A x[t] + B Δu[t] + K e[t],   Δy[t] = C x[t] + D Δu[t] + e[t]

whose one-step predictor is ``x̂[t+1] = (A - K C) x̂[t] + (B - K D) Δu[t] + K Δy[t]``.  The
``k``-step prediction ``ŷ(t | t-k)`` propagates ``x̂(t-k+1 | t-k)`` ``k - 1`` steps with the
known inputs and no measurement.  The deterministic part keeps the modal coordinates of
:mod:`tendonkit.plugins._modal` (poles bounded, integrators fixed at 1); ``K`` is free in the
coordinates of the real block-diagonal ``A`` that :func:`_modal.to_state_space` writes.  A
predictor that is not stable (``ρ(A - K C) ≥ 1``) is outside the domain: its residuals are a
large constant, so the trust region steps back.

The initial state of every experiment is the predictor's, ``x̂(0 | -1)``, fitted with the rest
(the stored ``x0`` is the first experiment's).  :func:`tendonkit.predict.predict` starts the
predictor from the free-run initial state it estimates and repeats the measurement for the
first ``k - 1`` samples; both agree once ``(A - K C)^t`` has decayed — a few samples on the
records the identifier needs.

Why a separate refinement: the simulation error (output error) is the criterion a model that
will be simulated is judged by, and it is consistent for the deterministic part whatever the
noise; the prediction error is the maximum-likelihood criterion when the disturbance is
process noise (Ljung 1999, §7.4), and the criterion of a model used for state estimation or
MPC.  Its Jacobian is by forward differences (one predictor run per parameter; the predictor
is a blocked state-space response, :func:`tendonkit.simulate.ss_response`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tendonkit.errors import DataError, SimulationError
from tendonkit.plugins import _modal
from tendonkit.predict import fitted_kalman_gain, k_step_states, kalman_gain
from tendonkit.schema import StateSpace
from tendonkit.simulate import ss_response

FloatArray = NDArray[np.float64]

#: Normalised residual of every sample where the predictor is unstable (outside the domain).
OUTSIDE = 1e3
#: Largest spectral radius of the predictor ``A - K C`` accepted.
PREDICTOR_RADIUS = 1.0 - 1e-9


def predictions(
    A: FloatArray,
    B: FloatArray,
    C: FloatArray,
    D: FloatArray,
    K: FloatArray,
    du: FloatArray,
    dy: FloatArray,
    x0: FloatArray,
    horizon: int,
) -> FloatArray:
    """``ŷ(t | t-horizon) - y0`` for every ``t`` (deviations), from the initial state ``x0``.

    Before ``t = horizon - 1`` the prediction is the free run from ``x0`` as far as the data
    go, so every sample has a prediction.
    """
    n, nu = B.shape
    AK, BK = A - K @ C, B - K @ D
    # the predictor's states: a state space driven by [Δu, Δy] whose outputs are its states
    X = ss_response(AK, np.hstack([BK, K]), np.eye(n), np.zeros((n, nu + K.shape[1])),
                    np.hstack([du, dy]), x0)  # fmt: skip
    return np.asarray(k_step_states(X, A, B, du, horizon) @ C.T + du @ D.T)


def initial_gains(
    layout: _modal.Layout, theta: FloatArray, exps: list[tuple[FloatArray, FloatArray]]
) -> list[FloatArray]:
    """Starts of ``K``, best first: the Kalman gain whose noise ratio predicts the first
    experiment best (:func:`tendonkit.predict.fitted_kalman_gain`), the gain for unit process
    and measurement noise (a stabilising one where ``(A, C)`` is detectable, integrators
    included), and none (an output-error model's predictor: ``A`` itself, stable for a stable
    model)."""
    A, B, C, D, _, u0, y0 = _modal.to_state_space(layout, theta)
    u, y = exps[0]
    starts = [fitted_kalman_gain(StateSpace(A=A, B=B, C=C, D=D), u - u0, y - y0)]
    try:
        starts.append(kalman_gain(A, C))
    except SimulationError:
        pass
    return [*starts, np.zeros_like(starts[0])]


class Problem:
    """Residuals of the normalised k-step prediction errors over θ = [modal θ, vec K]."""

    def __init__(
        self,
        layout: _modal.Layout,
        exps: list[tuple[FloatArray, FloatArray]],
        sy: FloatArray,
        horizon: int,
    ) -> None:
        self.layout, self.exps, self.sy, self.horizon = layout, exps, sy, horizon
        self.n_res = sum(y.size for _, y in exps)

    def split(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``z`` as ``(modal θ, K)``."""
        n, ny = self.layout.n_states, self.layout.ny
        return z[: self.layout.size], z[self.layout.size :].reshape(n, ny)

    def residuals(self, z: FloatArray) -> FloatArray:
        """Normalised prediction errors of every experiment, flattened; :data:`OUTSIDE` on
        every sample where the predictor is not stable or the prediction is not finite."""
        theta, K = self.split(z)
        A, B, C, D, x0s, u0, y0 = _modal.to_state_space(self.layout, theta)
        AK = A - K @ C
        if not np.all(np.isfinite(AK)) or max(abs(np.linalg.eigvals(AK)), default=0.0) > (
            PREDICTOR_RADIUS
        ):
            return np.full(self.n_res, OUTSIDE)
        parts = []
        with np.errstate(all="ignore"):
            for e, (u, y) in enumerate(self.exps):
                dy = y - y0
                pred = predictions(A, B, C, D, K, u - u0, dy, x0s[e], self.horizon)
                parts.append(((dy - pred) / self.sy).ravel())
        r = np.concatenate(parts)
        return r if np.all(np.isfinite(r)) else np.full(self.n_res, OUTSIDE)


@dataclass(frozen=True)
class Refined:
    """The outcome of :func:`refine`."""

    theta: FloatArray
    K: FloatArray
    before: float  # normalised RMS prediction error at the start
    after: float  # ... at the end (``before`` when the start is returned)
    evaluations: int
    jacobian: FloatArray | None  # at the optimum (None: the start was returned)
    residuals: FloatArray  # at the returned parameters


def refine(
    layout: _modal.Layout,
    theta: FloatArray,
    starts: list[FloatArray],
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
    horizon: int,
    max_nfev: int,
    tol: float = 1e-10,
) -> Refined:
    """Trust-region least squares of every parameter and ``K`` on the normalised
    ``horizon``-step prediction errors of ``exps``, from the first of ``starts`` (gains of
    :func:`initial_gains`) whose predictor is stable.

    The start is returned (with no Jacobian) when the refinement does not lower the error.

    Raises
    ------
    DataError
        When no start makes the predictor stable.
    """
    problem = Problem(layout, exps, sy, horizon)
    lo, hi = _modal.bounds(layout, _modal.STABLE_RADIUS)
    theta = np.clip(theta, lo, hi)
    for K in starts:
        z0 = np.concatenate([theta, K.ravel()])
        r0 = problem.residuals(z0)
        if not np.all(r0 == OUTSIDE):
            break
    else:
        raise DataError(
            "pem focus='prediction': no Kalman gain tried makes the predictor stable for the "
            "simulation-error model (its (A, C) may not be detectable); use focus='simulation'."
        )
    free = np.full(K.size, np.inf)
    bounds = (np.concatenate([lo, -free]), np.concatenate([hi, free]))
    sol = _modal.trust_region(problem.residuals, z0, "2-point", bounds, max_nfev, tol)
    before, after = _modal.rms(r0), _modal.rms(sol.fun)
    if not np.isfinite(after) or after > before:
        return Refined(theta, K, before, before, int(sol.nfev), None, r0)
    th, k = problem.split(np.asarray(sol.x))
    return Refined(th, k, before, after, int(sol.nfev), np.asarray(sol.jac), np.asarray(sol.fun))


def covariance(layout: _modal.Layout, refined: Refined, rep: StateSpace) -> dict[str, Any] | None:
    """Gauss–Newton covariance of the one-step prediction-error fit (:func:`refine`'s
    Jacobian and residuals at the optimum), mapped to the entries of ``rep`` that vary, ``K``
    among them (:func:`tendonkit.plugins._modal.entry_covariance`); None without a Jacobian.
    For one-step errors only: errors ``k`` steps ahead are correlated over ``k - 1`` samples,
    which ``λ (JᵀJ)⁺`` does not count (:class:`~tendonkit.plugins.pem.PEM` stores none then)."""
    if refined.jacobian is None:
        return None
    gn = _modal.gauss_newton_covariance(refined.jacobian, refined.residuals)
    if gn is None:
        return None
    z = np.concatenate([refined.theta, refined.K.ravel()])
    return _modal.entry_covariance(layout, z, gn[0], gn[1], rep)
