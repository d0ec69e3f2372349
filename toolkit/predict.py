"""k-step-ahead prediction for every representation of the schema.

State-space models run a steady-state Kalman predictor; ARX models and sparse maps are iterated
from the measured history.  Free-run simulation is :mod:`tendonkit.simulate`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ._kernel import state_loop
from ._simulate_arx import _arx_parts, _forced, arx_max_lag
from .errors import DataError, SimulationError
from .schema import ARX, Model, SparseMap, StateSpace
from .simulate import (
    _apply_blocks,
    _check_u,
    estimate_x0,
    inner_outputs,
    input_history,
    ss_theta_measured,
)
from .terms import CompiledTerms

FloatArray = NDArray[np.float64]


def predict(model: Model, u: FloatArray, y: FloatArray, k: int = 1) -> FloatArray:
    """k-step-ahead prediction ``ŷ(t | t-k)`` from measured inputs and outputs.

    State-space models run a steady-state Kalman predictor (the model's ``K`` when it has one,
    otherwise the gain for unit process and measurement noise) and propagate it ``k-1`` steps.
    ARX and sparse maps are iterated ``k`` times from the measured history.  The first ``k``
    samples (and the model's history length) repeat the measurement.

    Parameters
    ----------
    model : Model
        Any representation; output blocks only if they are all ``polynomial`` curves (a
        Wiener model: its inner signal is predicted from the outputs taken back through them).
    u, y : array
        Measured inputs (n, nu) and outputs (n, ny).
    k : int
        Prediction horizon in samples, >= 1.
    """
    u, y_checked = _check_u(model, u, y)
    assert y_checked is not None
    y = y_checked
    if k < 1:
        raise DataError(f"The prediction horizon k must be >= 1, found {k}.")
    if k > 1 and not predicts_ahead(model):
        raise SimulationError(
            f"{k}-step prediction of a state space with terms with a memory (play, bouc_wen, slew_lag) would "
            "need their state estimated at every sample; use k=1 or a simulation."
        )
    if model.is_wiener:
        # A Wiener model: the representation predicts its inner signal from the measured
        # outputs taken back through the curves, and the curves give the outputs.
        inner = model.replace(output_blocks=())
        return _apply_blocks(
            model.output_blocks, model.output_names, predict(inner, u, inner_outputs(model, y), k)
        )
    # an ARX's delayed inputs before the record: as simulate starts them (input_history)
    before = input_history(model, u, y)
    ub = _apply_blocks(model.input_blocks, model.input_names, u, True, before)
    rep = model.representation
    if isinstance(rep, StateSpace) and rep.terms:
        return _predict_ss_terms(model, rep, ub, y, k)
    if isinstance(rep, StateSpace) and rep.has_offsets:
        # the Kalman predictor runs on the deviations from the operating point
        u0, y0 = rep.operating_point
        lin = dataclasses.replace(rep, u0=None, y0=None)
        return _predict_ss(lin, ub - u0, y - y0, k) + y0
    if isinstance(rep, StateSpace):
        return _predict_ss(rep, ub, y, k)
    return _predict_recursive(model, ub, y, k)


def predicts_ahead(model: Model) -> bool:
    """Whether :func:`predict` takes ``model`` beyond one step (``k > 1``).

    A state space whose terms hold an operator with a memory (play, bouc_wen, slew_lag)
    predicts one step only: over more, the operator's state would have to be estimated at
    every sample.  Every other structure :func:`predict` takes predicts any horizon.
    """
    rep = model.representation
    return not (isinstance(rep, StateSpace) and any(t.stateful for t in rep.terms))


def _predict_ss_terms(
    model: Model, rep: StateSpace, u: FloatArray, y: FloatArray, k: int
) -> FloatArray:
    """k-step prediction with terms: Θ from measurements up to t-k, from predictions after."""
    assert rep.E is not None
    ny = rep.C.shape[0]
    theta = ss_theta_measured(model, u, y)  # Θ reads the raw signals
    lin = StateSpace(
        rep.A, np.hstack([rep.B, rep.E]), rep.C, np.hstack([rep.D, np.zeros((ny, rep.E.shape[1]))])
    )
    # the linear part acts on deviations from the operating point (zero without one)
    u0, y0 = rep.operating_point
    y_raw, u, y = y, u - u0, y - y0
    ua = np.hstack([u, theta])
    K = rep.K if rep.K is not None else fitted_kalman_gain(lin, ua, y)
    Xp = _one_step_states(lin, K, ua, y)
    uD = u @ rep.D.T
    first = Xp[:-1] @ rep.C.T + uD + y0
    if k == 1:
        return first
    ct = CompiledTerms(rep.terms)
    L = max((t.max_lag for t in rep.terms), default=1)
    names_in, names_out = model.input_names, model.output_names
    u_raw = u + u0
    # Pass i holds x̂(t | t-i) and ŷ(t | t-i) for every t (vectorised over t).  The terms at
    # t-1 read each output at lag l as known at t-i: measured where l >= i, else the
    # prediction ŷ(t-1-l | t-i) of horizon i - l.
    states = Xp[:-1]
    outs = [y_raw, first]
    uB = _past(u, 1, u[0]) @ rep.B.T
    # the terms' input columns are the same in every pass
    inputs = {
        (name, lag): _past(u_raw, 1 + lag, u_raw[0])[:, names_in.index(name)]
        for name, lag in ct.keys
        if name not in names_out
    }
    for i in range(1, k):
        vals = []
        for name, lag in ct.keys:
            if name in names_out:
                src = outs[i - lag] if lag < i else y_raw
                vals.append(_past(src, 1 + lag, y_raw[0])[:, names_out.index(name)])
            else:
                vals.append(inputs[name, lag])
        theta = ct.evaluate(np.array(vals)).T
        states = _past(states, 1, states[0]) @ rep.A.T + uB + theta @ rep.E.T
        outs.append(states @ rep.C.T + uD + y0)
    out = outs[k].copy()
    out[: k - 1 + L] = y_raw[: k - 1 + L]
    return np.asarray(out)


def _predict_ss(rep: StateSpace, u: FloatArray, y: FloatArray, k: int) -> FloatArray:
    K = rep.K if rep.K is not None else fitted_kalman_gain(rep, u, y)
    X = k_step_states(_one_step_states(rep, K, u, y)[:-1], rep.A, rep.B, u, k)
    out = y.copy()
    out[k - 1 :] = X[k - 1 :] @ rep.C.T + u[k - 1 :] @ rep.D.T
    return out


def k_step_states(
    X1: FloatArray, A: FloatArray, B: FloatArray, u: FloatArray, k: int
) -> FloatArray:
    """``x̂(t | t-k)`` for every ``t`` from the one-step predictor's states ``X1[t] = x̂(t | t-1)``:
    each of the ``k - 1`` passes propagates every state one step with the known inputs,
    ``x̂(t | t-j-1) = A x̂(t-1 | t-j-1) + B u[t-1]`` (vectorised over ``t``).  Before
    ``t = k - 1`` the states are those propagated from ``X1[0]``, as far as the data go."""
    X = X1
    for _ in range(k - 1):
        shifted = np.empty_like(X)
        shifted[0] = X1[0]
        shifted[1:] = X[:-1] @ A.T + u[:-1] @ B.T
        X = shifted
    return X


def _one_step_states(rep: StateSpace, K: FloatArray, u: FloatArray, y: FloatArray) -> FloatArray:
    """``Xp[t] = x̂(t | t-1)`` of the predictor with gain ``K``, for t = 0..N."""
    A, B, C, D = rep.A, rep.B, rep.C, rep.D
    AK, BK = A - K @ C, B - K @ D
    drive = np.vstack([u @ BK.T + y @ K.T, np.zeros((1, rep.n_states))])
    x0 = np.asarray(estimate_x0(rep, u, y), dtype=float).ravel()
    return np.asarray(state_loop(np.ascontiguousarray(AK, dtype=float), drive, x0))


def fitted_kalman_gain(
    rep: StateSpace, u: FloatArray, y: FloatArray, max_samples: int = 5000
) -> FloatArray:
    """Predictor gain for a model without a noise model, chosen from the data.

    The gain solves the Kalman DARE with ``Q = q I`` and ``R = I``; ``q`` is picked from a
    log grid (1e-8 .. 1e2) by the one-step prediction error on the first ``max_samples``
    samples.  Pure output noise selects ``q -> 0`` (the predictor then trusts the model),
    unmodelled disturbances select larger ``q``.
    """
    n, ny = rep.n_states, rep.C.shape[0]
    uu, yy = u[:max_samples], y[:max_samples]
    best, best_err = np.zeros((n, ny)), np.inf
    for q in (1e-8, 1e-6, 1e-4, 1e-2, 1.0, 1e2):
        try:
            K = kalman_gain(rep.A, rep.C, q * np.eye(n), np.eye(ny))
        except SimulationError:
            continue
        Xp = _one_step_states(rep, K, uu, yy)[:-1]
        err = float(np.mean((yy - Xp @ rep.C.T - uu @ rep.D.T) ** 2))
        if err < best_err:
            best, best_err = K, err
    return best


def kalman_gain(
    A: FloatArray, C: FloatArray, Q: FloatArray | None = None, R: FloatArray | None = None
) -> FloatArray:
    """Steady-state predictor gain for ``x+ = Ax + w``, ``y = Cx + v`` (unit covariances by default)."""
    # lazy: heavy (scipy)
    from scipy.linalg import solve_discrete_are

    n, ny = A.shape[0], C.shape[0]
    Q = np.eye(n) if Q is None else Q
    R = np.eye(ny) if R is None else R
    try:
        P = solve_discrete_are(A.T, C.T, Q, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise SimulationError(f"No steady-state Kalman gain for this model: {exc}") from None
    return np.asarray(A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R))


def _predict_recursive(model: Model, u: FloatArray, y: FloatArray, k: int) -> FloatArray:
    """Iterate one-step predictions: pass j uses predictions of pass j-i at lag i < j."""
    rep = model.representation
    passes = [y]  # passes[0] = measurement
    # An ARX's input part (the offset, the input lags and the terms that read inputs only) is
    # the same in every pass: prepared once, k passes cost the output part only.
    arx = _ArxPasses.prepare(model, rep, u) if isinstance(rep, ARX) else None
    for j in range(1, k + 1):
        passes.append(_one_pass(model, rep, u, passes, j, arx))
    return passes[k].copy()


def _past(x: FloatArray, lag: int, first: FloatArray) -> FloatArray:
    """``x`` delayed by ``lag`` samples, its first ``lag`` rows ``first``."""
    out = np.empty_like(x)
    out[lag:] = x[: max(x.shape[0] - lag, 0)]
    out[:lag] = first
    return out


def _terms_sum(
    model: Model, ct: CompiledTerms, coef: FloatArray, u: FloatArray, past_y: Any
) -> FloatArray:
    """``Σ c_i term_i`` of an ARX's terms ``ct`` (coefficient rows ``coef``) for every t."""
    vals = []
    for name, lag in ct.keys:
        if name in model.output_names:
            vals.append(past_y(lag)[:, model.output_names.index(name)])
        else:
            vals.append(_past(u, lag, u[0])[:, model.input_names.index(name)])
    return np.asarray(ct.evaluate(np.array(vals)).T @ coef)


@dataclasses.dataclass(frozen=True)
class _ArxPasses:
    """An ARX's prediction split for :func:`_predict_recursive`: ``fixed``, what it takes from
    the inputs alone for every t (the offset, the input lags, the terms that read no output),
    and the terms that read an output (``moving``, with their coefficient rows), evaluated
    again in every pass."""

    fixed: FloatArray
    moving: CompiledTerms | None
    coef: FloatArray | None

    @classmethod
    def prepare(cls, model: Model, rep: ARX, u: FloatArray) -> _ArxPasses:
        _, G, off = _arx_parts(model, rep)
        lags = len(G) - 1
        fixed = _forced(np.vstack([np.repeat(u[:1], lags, 0), u]), G, off, lags, u.shape[0])
        coefs = rep.term_coefficients
        if not rep.terms or coefs is None:
            return cls(fixed, None, None)
        outputs = set(model.output_names)
        reads = [bool(t.signals & outputs) for t in rep.terms]
        inputs_only = [i for i, r in enumerate(reads) if not r]
        moving = [i for i, r in enumerate(reads) if r]
        if inputs_only:
            ct = CompiledTerms([rep.terms[i] for i in inputs_only])
            fixed += _terms_sum(model, ct, coefs[inputs_only], u, None)
        if not moving:
            return cls(fixed, None, None)
        return cls(fixed, CompiledTerms([rep.terms[i] for i in moving]), coefs[moving])


def _one_pass(
    model: Model,
    rep: Any,
    u: FloatArray,
    passes: list[FloatArray],
    j: int,
    arx: _ArxPasses | None,
) -> FloatArray:
    """Prediction ``ŷ(t | t-j)`` for every t, vectorised over t (``arx``: an ARX's parts,
    :class:`_ArxPasses`, when the caller has them)."""

    def past_y(lag: int) -> FloatArray:
        return _past(passes[j - lag] if lag < j else passes[0], lag, passes[0][0])

    def past_u(lag: int) -> FloatArray:
        return _past(u, lag, u[0])

    if isinstance(rep, ARX):
        assert arx is not None  # prepared once by the caller
        pred = arx.fixed.copy()
        for i, Ai in enumerate(rep.A, start=1):
            pred -= past_y(i) @ Ai.T
        if arx.moving is not None and arx.coef is not None:
            pred += _terms_sum(model, arx.moving, arx.coef, u, past_y)
        L = arx_max_lag(rep, len(model.inputs))
        pred[:L] = passes[0][:L]
        return pred
    assert isinstance(rep, SparseMap)
    ct = CompiledTerms(rep.terms)
    states = [s.name for s in model.states]
    full_states = len(rep.output_states) == rep.n_states
    if not full_states:
        raise SimulationError(
            "k-step prediction of a sparse_map needs every state measured (states = outputs)."
        )
    vals = []
    for name, lag in ct.keys:
        if name in states:
            col = list(rep.output_states).index(states.index(name))
            vals.append(past_y(lag + 1)[:, col])
        else:
            vals.append(past_u(lag + 1)[:, model.input_names.index(name)])
    X = ct.evaluate(np.array(vals)).T @ rep.coefficients
    pred = X[:, list(rep.output_states)]
    L = max((t.max_lag for t in rep.terms), default=0) + 1
    pred[:L] = passes[0][:L]
    return pred
