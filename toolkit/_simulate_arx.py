"""ARX simulation: the linear recursion, its shift-register fast path, and term models.

Split from :mod:`tendonkit.simulate` (which re-exports :func:`arx_max_lag`).  Models with
nonlinear terms run a loop over samples; terms of inputs only are computed for the whole
record first, and terms affine in one past output (bilinear ``u·y``) become time-varying
coefficients of the recursion, so only the other terms are evaluated step by step.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from . import _kernel
from ._response import Initial, ss_response
from .errors import DataError
from .realize import arx_lag_matrices, arx_to_state_space
from .schema import ARX, Model
from .terms import CompiledTerms, Factor, Term, scalar_evaluator, series_getter

FloatArray = NDArray[np.float64]


def arx_max_lag(rep: ARX, nu: int) -> int:
    """Number of samples of history an ARX model needs."""
    L = len(arx_lag_matrices(rep, nu)) - 1
    return max(rep.na, L, max((t.max_lag for t in rep.terms), default=0), 1)


def _arx_parts(model: Model, rep: ARX) -> tuple[FloatArray, list[FloatArray], FloatArray]:
    ny, nu = len(model.outputs), len(model.inputs)
    Acat = np.hstack(rep.A) if rep.A else np.zeros((ny, 0))
    G = arx_lag_matrices(rep, nu) if rep.B else [np.zeros((ny, nu))]
    off = np.zeros(ny) if rep.offset is None else rep.offset
    return Acat, G, off


def _forced(U: FloatArray, G: list[FloatArray], off: FloatArray, L: int, N: int) -> FloatArray:
    """Offset plus ``Σ_l G_l u[k-l]`` for every sample ``k`` (``U`` padded with ``L`` samples)."""
    forced = np.zeros((N, G[0].shape[0])) + off
    for lag, Gl in enumerate(G):
        if np.any(Gl):
            forced += U[L - lag : L - lag + N] @ Gl.T
    return forced


def _sim_arx(
    model: Model,
    rep: ARX,
    u: FloatArray,
    y: FloatArray | None,
    initial: Initial,
    compiled: bool = True,
    window: int | None = None,
) -> FloatArray:
    ny, nu = len(model.outputs), len(model.inputs)
    N = u.shape[0]
    Acat, G, off = _arx_parts(model, rep)
    L = arx_max_lag(rep, nu)
    # history buffers padded with L samples before t=0 (zero; every later row is written)
    Y = np.empty((N + L, ny))
    Y[:L] = 0.0
    U = np.empty((N + L, nu))
    U[:L] = 0.0
    U[L:] = u
    start = 0
    if isinstance(initial, str) and initial == "estimate":
        assert y is not None
        start = min(L, N, window or L)
        Y[L : L + start] = y[:start]
        U[:L] = u[0]  # inputs before the record: held at the first sample
        Y[:L] = y[0]
    elif not isinstance(initial, str):
        raise DataError("ARX models take initial='zero', 'model' or 'estimate', not an array.")
    linear = not rep.terms or rep.term_coefficients is None
    if linear and ny > 1 and N - start >= 512 and not compiled:
        Y[L + start :] = _arx_block(rep, U, Y, off, L, start, N)
        return Y[L:]
    na = rep.na
    coef = rep.term_coefficients
    if compiled and linear and ny > 1:
        used = [lag for lag, Gl in enumerate(G) if np.any(Gl)] or [0]
        g0, g1 = used[0], used[-1] + 1  # the input delay, and past the last lag used
        _kernel.arx_linear_loop(
            U,
            Y,
            np.ascontiguousarray(np.array(G[g0:g1], dtype=float).reshape(g1 - g0, ny, nu)),
            g0,
            np.ascontiguousarray(off, dtype=float),
            np.ascontiguousarray(Acat, dtype=float),
            na,
            start,
            L,
        )
        return Y[L:]
    if compiled and not (linear and ny == 1):
        # Every term is evaluated per step from flat arrays (no time-varying split needed).
        terms = () if linear else rep.terms
        flat = _kernel.flatten(
            terms,
            {n: j for j, n in enumerate(model.input_names)},
            {n: j for j, n in enumerate(model.output_names)},
        )
        coef_t = np.zeros((ny, 0)) if coef is None or linear else np.ascontiguousarray(coef.T)
        # terms of inputs only: each distinct factor computed once for the whole record
        pre, base, fac = _kernel.input_bases(flat)
        series = _kernel.input_series(
            U, fac.col, fac.diff, fac.src2, fac.col2, fac.code, fac.power, fac.scale,
            fac.offset, fac.param, fac.weight,
        )  # fmt: skip
        _kernel.run_terms(
            _kernel.arx_loop,
            U,
            Y,
            np.ascontiguousarray(np.array(G, dtype=float).reshape(len(G), ny, nu)),
            np.ascontiguousarray(off, dtype=float),
            np.ascontiguousarray(Acat, dtype=float),
            na,
            start,
            L,
            coef_t,
            pre,
            base,
            series,
            flat=flat,
        )
        return Y[L:]
    # Input contribution for every sample at once (the inputs are known).
    forced = _forced(U, G, off, L, N)
    if linear and ny == 1 and start < N:
        # Single output: the recursion is an IIR filter of the input contribution (C speed).
        # lazy: heavy (scipy.signal)
        from scipy.signal import lfilter, lfiltic

        a = np.concatenate([[1.0], [float(Ai[0, 0]) for Ai in rep.A]])
        zi = lfiltic([1.0], a, y=Y[L + start - 1 :: -1, 0][: max(na, 1)]) if na else None
        if zi is None:
            Y[L + start :, 0] = forced[start:, 0]
        else:
            Y[L + start :, 0] = lfilter([1.0], a, forced[start:, 0], zi=zi)[0]
        return Y[L:]
    ct = None if linear else CompiledTerms(rep.terms)
    if ct is None or coef is None:
        for k in range(start, N):
            kk = k + L
            acc = forced[k].copy()
            if na:
                acc -= Acat @ Y[kk - na : kk][::-1].reshape(-1)
            Y[kk] = acc
        return Y[L:]
    # Nonlinear terms.  Terms of inputs only are known for every sample in advance; terms
    # affine in one past output (an input-dependent gain, e.g. bilinear u·y) make the
    # recursion linear with time-varying coefficients; only the rest are evaluated per step.
    M, forced, general, gcoef = _time_varying_part(model, rep, U, forced, L, N, coef)
    width = M.shape[2] // ny
    ct = CompiledTerms(general) if general else None
    evaluate = scalar_evaluator(ct) if ct is not None else None
    reads: list[tuple[FloatArray, int, int]] = []
    if ct is not None:
        cols = {
            **{n: (U, j) for j, n in enumerate(model.input_names)},
            **{n: (Y, j) for j, n in enumerate(model.output_names)},
        }
        reads = [(cols[name][0], cols[name][1], lag) for name, lag in ct.keys]
    gcoef_t = gcoef.T.copy()
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(start, N):
            kk = k + L
            acc = forced[k] + M[k] @ Y[kk - width : kk][::-1].reshape(-1)
            if evaluate is not None:
                try:
                    theta = evaluate([float(arr[kk - lag, j]) for arr, j, lag in reads])
                except (OverflowError, ValueError):  # the simulation diverged
                    Y[kk:] = np.nan
                    break
                acc += gcoef_t @ theta
            Y[kk] = acc
    bad = ~np.isfinite(Y[L:]).all(axis=1)
    if bad.any():  # diverged: nothing after the first non-finite sample is meaningful
        Y[L + int(np.argmax(bad)) :] = np.nan
    return Y[L:]


def _time_varying_part(
    model: Model,
    rep: ARX,
    U: FloatArray,
    forced: FloatArray,
    L: int,
    N: int,
    coef: FloatArray,
) -> tuple[FloatArray, FloatArray, list[Term], FloatArray]:
    """Split an ARX model's terms for simulation.

    Returns ``M`` of shape ``(N, ny, width·ny)`` with ``y[k] = forced[k] + M[k] ·
    [y[k-1]; …; y[k-width]] + general terms``, the input contribution including the terms of
    inputs only, and the remaining (general) terms with their coefficients.
    """
    ny = len(model.outputs)
    inputs, outputs = set(model.input_names), list(model.output_names)
    getter = series_getter({n: U[:, j] for j, n in enumerate(model.input_names)})
    width = max(rep.na, 1)
    affine: list[tuple[int, Factor, FloatArray]] = []
    general: list[Term] = []
    gcoef: list[FloatArray] = []
    forced = forced.copy()
    for i, term in enumerate(rep.terms):
        ins = [f for f in term.factors if f.signal in inputs]
        outs = [f for f in term.factors if f.signal not in inputs]
        # A hysteresis operator runs from the first simulated step, as in the kernel: general.
        if (
            term.stateful
            or any(f.minus for f in term.factors)
            or len(outs) > 1
            or (
                outs
                and ((outs[0].fn, outs[0].power, outs[0].diff) != ("pow", 1, 0) or outs[0].lag < 1)
            )
        ):
            general.append(term)
            gcoef.append(coef[i])
            continue
        g = np.ones(N)
        if ins:
            known = CompiledTerms((Term(tuple(ins)),))
            g = known.evaluate(np.array([getter(n, lag) for n, lag in known.keys]))[0][L : L + N]
        if not outs:
            forced += np.outer(g, coef[i])
            continue
        f = outs[0]
        width = max(width, f.lag)
        affine.append((i, f, g))
        # (y - offset)·scale: the constant part is known in advance
        forced -= np.outer(g * f.offset * f.scale, coef[i])
    M = np.zeros((N, ny, width * ny))
    for lag, Ai in enumerate(rep.A, start=1):
        M[:, :, (lag - 1) * ny : lag * ny] -= Ai
    for i, f, g in affine:
        col = (f.lag - 1) * ny + outputs.index(f.signal)
        M[:, :, col] += np.outer(g * f.scale, coef[i])
    return M, forced, general, np.array(gcoef).reshape(len(gcoef), ny)


def _arx_block(
    rep: ARX, U: FloatArray, Y: FloatArray, off: FloatArray, L: int, start: int, N: int
) -> FloatArray:
    """Linear ARX from sample ``start`` on, through its exact shift-register realisation.

    The offset enters as one more input that is always 1; the realisation's initial state is
    the history held in the padded buffers ``U`` and ``Y`` (``L`` samples before t = 0).
    """
    ny, nu = Y.shape[1], U.shape[1]
    B = tuple(np.hstack([b, np.zeros((ny, 1))]) for b in rep.B) or (np.zeros((ny, nu + 1)),)
    lin = dataclasses.replace(
        rep, B=B, nk=(*rep.nk, 0), offset=None, terms=(), term_coefficients=None
    )
    ss = arx_to_state_space(lin, nu + 1)
    # the offset column enters at lag 0 only (nk = 0, first B matrix)
    ss.D[:, nu] = off
    if rep.na:
        ss.B[:ny, nu] = off
    Ua = np.hstack([U, np.ones((U.shape[0], 1))])
    kk = L + start
    Lg = (ss.A.shape[0] - ny * rep.na) // (nu + 1)
    x0 = (
        np.concatenate(
            [Y[kk - i] for i in range(1, rep.na + 1)] + [Ua[kk - j] for j in range(1, Lg + 1)]
        )
        if ss.A.shape[0]
        else np.zeros(0)
    )
    return ss_response(ss.A, ss.B, ss.C, ss.D, Ua[kk : L + N], x0)
