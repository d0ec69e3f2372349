"""Compiled simulation kernel: the per-sample loops of :mod:`tendonkit.simulate`, in numba.

Every recursion that cannot be vectorised (an ARX model with nonlinear terms or time-varying
coefficients, a state space with terms, a sparse map, the play and rate-limit blocks) runs here
as machine code.  The model is never compiled: its terms are *interpreted* from flat arrays
(:class:`FlatTerms`), so the few kernels below are compiled once per machine (``cache=True``
keeps them on disk) and serve every model — diagnose builds hundreds of candidate models and
pays no compiler per model.  docs/design-decisions.md ("A compiled kernel that interprets
terms") says why this design and not code generation per model.

The numpy code in :mod:`tendonkit.simulate` stays as the reference (``engine="reference"``);
``tests/core/test_kernel.py`` holds the two equal to 1e-12 on random models of every kind,
including where a simulation diverges.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: The factor functions by code, in the order of ``tendonkit.terms.FUNCTIONS`` (which checks
#: it); from ``play`` on they are hysteresis operators with a state.
CODES = (
    "pow", "sin", "cos", "tanh", "sign", "abs", "dead_zone", "sat", "relu", "play", "bouc_wen",
    "slew_lag",
)  # fmt: skip
_CODE = {name: i for i, name in enumerate(CODES)}
PLAY, BOUC_WEN, SLEW_LAG = _CODE["play"], _CODE["bouc_wen"], _CODE["slew_lag"]
#: Integer exponents up to this are evaluated as repeated products ``((z·z)·z)…``, here and in
#: the numpy reference (``terms._product_power``) in the same order, so a factor's value is the
#: same number in both: ``pow`` costs about twenty products per element, and polynomial terms
#: (a stiffness, a static curve) are much of what diagnose simulates and regresses.
MAX_PRODUCT_POWER = 8


@dataclass(frozen=True)
class FlatTerms:
    """Terms as flat arrays (one row per factor; ``ptr[t]:ptr[t+1]`` are term ``t``'s factors).

    ``src`` says which buffer a factor reads (0: the first, e.g. inputs; 1: the second, outputs
    or states), ``col`` its column, ``lag``/``diff`` how far back; ``src2``/``col2`` the
    ``minus`` signal of a relative factor (``src2 = -1``: none) and ``weight`` its weight.
    """

    ptr: IntArray
    src: IntArray
    col: IntArray
    lag: IntArray
    diff: IntArray
    src2: IntArray
    col2: IntArray
    code: IntArray
    power: FloatArray
    scale: FloatArray
    offset: FloatArray
    param: FloatArray
    param2: FloatArray
    weight: FloatArray

    @property
    def n_terms(self) -> int:
        """Number of terms."""
        return int(self.ptr.shape[0] - 1)


def flatten(terms: Sequence[Any], first: Mapping[str, int], second: Mapping[str, int]) -> FlatTerms:
    """Flat arrays for ``terms`` reading signals by name from two buffers."""
    rows: list[
        tuple[int, int, int, int, int, int, int, float, float, float, float, float, float]
    ] = []
    ptr = [0]

    def where(name: str) -> tuple[int, int]:
        return (0, first[name]) if name in first else (1, second[name])

    for t in terms:
        for f in t.factors:
            src, col = where(f.signal)
            src2, col2 = where(f.minus) if f.minus else (-1, 0)
            rows.append(
                (src, col, f.lag, f.diff, src2, col2, _CODE[f.fn], float(f.power), f.scale,
                 f.offset, f.param, f.param2, float(f.weight))
            )  # fmt: skip
        ptr.append(len(rows))
    cols = list(zip(*rows, strict=True)) if rows else [()] * 13
    i = [np.asarray(c, dtype=np.int64) for c in cols[:7]]
    x = [np.asarray(c, dtype=np.float64) for c in cols[7:]]
    return FlatTerms(
        np.asarray(ptr, dtype=np.int64), i[0], i[1], i[2], i[3], i[4], i[5], i[6], x[0], x[1],
        x[2], x[3], x[4], x[5],
    )  # fmt: skip


# -- the kernels ---------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _fn(code: int, z: float, power: float, param: float) -> float:  # pragma: no cover - numba
    if code == 0:
        if power == 1.0:
            return z
        if 1.0 < power <= MAX_PRODUCT_POWER and power == int(power):
            out = z
            for _ in range(int(power) - 1):
                out = out * z
            return out
        return z**power
    if code == 1:
        return np.sin(z)
    if code == 2:
        return np.cos(z)
    if code == 3:
        return np.tanh(z)
    if code == 4:
        if z > 0.0:
            return 1.0
        if z < 0.0:
            return -1.0
        return 0.0 if z == 0.0 else z
    if code == 5:
        return abs(z)
    if code == 6:
        m = abs(z) - param
        if m < 0.0:
            m = 0.0
        return m if z > 0.0 else (-m if z < 0.0 else 0.0 * m)
    if code == 7:
        return min(max(z, -param), param)
    m = z - param
    return m if m > 0.0 else 0.0


@njit(cache=True, nogil=True, inline="always")
def hysteresis_step(code, z, param, param2, st):  # pragma: no cover - numba
    """One sample of a hysteresis operator: ``(value, d value / d z)``, its state ``st`` advanced.

    ``st`` holds two numbers, NaN before the first sample: the play's or the slew lag's output,
    or the Bouc-Wen operator's previous ``z`` and its ``h`` (the reference is
    ``terms._step_stateful``).
    """
    a = st[0]
    if code == PLAY:
        if np.isnan(a):
            st[0] = z
            return z, 1.0
        p = min(max(a, z - param), z + param)
        st[0] = p
        return p, 1.0 if p != a else 0.0
    if code == SLEW_LAG:
        if np.isnan(a):
            st[0] = z
            return z, 1.0
        step = param * (z - a)
        r = a + min(max(step, -param2), param2)
        st[0] = r
        return r, param if abs(step) < param2 else 0.0
    if np.isnan(a):  # Bouc-Wen, from h = 0
        st[0] = z
        st[1] = 0.0
        return 0.0, 1.0
    h = st[1]
    d = z - a
    s = 1.0 if d > 0 else (-1.0 if d < 0 else 0.0)
    der = 1.0 - param * s * h - param2 * abs(h)
    st[0] = z
    st[1] = h + d - param * abs(d) * h - param2 * d * abs(h)
    return st[1], der


@njit(cache=True, nogil=True)
def hysteresis_record(code, z, param, param2):  # pragma: no cover - numba
    """Values and derivatives of a hysteresis operator run along the record ``z``."""
    st = np.full(2, np.nan)
    val = np.empty(z.shape[0])
    der = np.empty(z.shape[0])
    for k in range(z.shape[0]):
        val[k], der[k] = hysteresis_step(code, z[k], param, param2, st)
    return val, der


@njit(cache=True, nogil=True, inline="always")
def _at(buf, r, c, d):  # pragma: no cover - numba
    """``buf[r, c]``, minus ``buf[r - d, c]`` when ``d`` (a difference over ``d`` samples)."""
    return buf[r, c] - buf[r - d, c] if d else buf[r, c]


@njit(cache=True, nogil=True, inline="always")
def _terms_at(  # pragma: no cover - numba
    a, b, kk, ptr, src, col, lag, diff, src2, col2, code, power, scale, offset, param, param2,
    weight, st, theta, skip,
):  # fmt: skip
    for t in range(ptr.shape[0] - 1):
        if skip[t]:  # computed by the caller (:func:`arx_loop`'s terms of inputs only)
            continue
        prod = 1.0
        for f in range(ptr[t], ptr[t + 1]):
            # index each buffer in its own branch: binding ``buf = a if ... else b`` makes
            # numba reference-count an array view per factor and sample (2.5x slower), and so
            # does a helper that takes both buffers (4.5x on an ARX with three terms)
            r, d = kk - lag[f], diff[f]
            s = _at(a, r, col[f], d) if src[f] == 0 else _at(b, r, col[f], d)
            if src2[f] >= 0:  # relative to a second signal: (s - s_prev) - w·(q - q_prev)
                s = s - weight[f] * (
                    _at(a, r, col2[f], d) if src2[f] == 0 else _at(b, r, col2[f], d)
                )
            z = (s - offset[f]) * scale[f]
            if code[f] >= PLAY:
                prod *= hysteresis_step(code[f], z, param[f], param2[f], st[f])[0]
            else:
                prod *= _fn(code[f], z, power[f], param[f])
        theta[t] = prod


@njit(cache=True, nogil=True)
def arx_loop(  # pragma: no cover - numba
    U, Y, G, off, Acat, na, start, L, coef_t, pre, base, series, ptr, src, col, lag, diff, src2,
    col2, code, power, scale, offset, param, param2, weight, st,
):  # fmt: skip
    """``Y[k+L] = off + Σ_l G[l]·U[k+L-l] - Acat·[Y[k+L-1]; …; Y[k+L-na]] + coef_t·θ(k)``.

    From sample ``start`` on; ``G`` holds the input matrices per lag (delays included), ``Y``
    (padded with ``L`` samples of history) is written in place; the first sample where an
    output turns non-finite and every later one are NaN.  The terms flagged ``pre`` (of
    inputs only, :func:`input_bases`) are products of the rows of ``series``
    (:func:`input_series`) read at their factors' lags; the others are evaluated here.
    """
    N = U.shape[0] - L
    ny, nu = Y.shape[1], U.shape[1]
    nt = ptr.shape[0] - 1
    nl = G.shape[0]
    n_used = 0
    lags = np.empty(nl, dtype=np.int64)
    for g in range(nl):
        if np.any(G[g] != 0.0):
            lags[n_used] = g
            n_used += 1
    theta = np.empty(nt)
    for k in range(start, N):
        kk = k + L
        if nt:
            _terms_at(
                U, Y, kk, ptr, src, col, lag, diff, src2, col2, code, power, scale, offset, param,
                param2, weight, st, theta, pre,
            )  # fmt: skip
            for t in range(nt):
                if pre[t]:
                    prod = 1.0
                    for f in range(ptr[t], ptr[t + 1]):
                        prod *= series[base[f], kk - lag[f]]
                    theta[t] = prod
        ok = True
        for i in range(ny):
            acc = off[i]
            for m in range(n_used):
                g = lags[m]
                row = kk - g
                for j in range(nu):
                    acc += G[g, i, j] * U[row, j]
            for w in range(na):
                for j in range(ny):
                    acc -= Acat[i, w * ny + j] * Y[kk - 1 - w, j]
            for t in range(nt):
                acc += coef_t[i, t] * theta[t]
            Y[kk, i] = acc
            if not np.isfinite(acc):
                ok = False
        if not ok:
            Y[kk:] = np.nan
            return


@njit(cache=True, nogil=True)
def arx_linear_loop(U, Y, G, g0, off, Acat, na, start, L):  # pragma: no cover - numba
    """Linear ARX: ``Y[k+L] = off + Σ_l G[l]·U[k+L-g0-l] - Acat·[Y[k+L-1]; …; Y[k+L-na]]``.

    What :func:`arx_loop` does without terms (``G`` starts at lag ``g0``, the input delay),
    with the sums split over two accumulators each (even and odd lags): the chains of
    dependent additions are half as long, which is what bounds a loop this small.  Same NaN
    rule as :func:`arx_loop`.
    """
    N = U.shape[0] - L
    ny, nu = Y.shape[1], U.shape[1]
    nl = G.shape[0]
    for k in range(start, N):
        kk = k + L
        ok = True
        for i in range(ny):
            a0 = off[i]
            a1 = 0.0
            g = 0
            while g + 1 < nl:
                r0 = kk - g0 - g
                for j in range(nu):
                    a0 += G[g, i, j] * U[r0, j]
                    a1 += G[g + 1, i, j] * U[r0 - 1, j]
                g += 2
            if g < nl:
                r0 = kk - g0 - g
                for j in range(nu):
                    a0 += G[g, i, j] * U[r0, j]
            b0 = 0.0
            b1 = 0.0
            for w in range(na):
                row = kk - 1 - w
                if w & 1:
                    for j in range(ny):
                        b1 += Acat[i, w * ny + j] * Y[row, j]
                else:
                    for j in range(ny):
                        b0 += Acat[i, w * ny + j] * Y[row, j]
            acc = (a0 + a1) - (b0 + b1)
            Y[kk, i] = acc
            if not np.isfinite(acc):
                ok = False
        if not ok:
            Y[kk:] = np.nan
            return


@njit(cache=True, nogil=True)
def ss_terms_loop(  # pragma: no cover - numba
    U, Y, u, x, A, B, C, D, E, L, ptr, src, col, lag, diff, src2, col2, code, power, scale,
    offset, param, param2, weight, st,
):  # fmt: skip
    """State space with terms: ``y = Cx + Du``, ``x⁺ = Ax + Bu + Eθ``; θ reads ``U`` and ``Y``."""
    N = u.shape[0]
    n, ny, nu = A.shape[0], C.shape[0], u.shape[1]
    theta = np.empty(ptr.shape[0] - 1)
    none = np.zeros(theta.shape[0], dtype=np.bool_)
    xn = np.empty(n)
    for k in range(N):
        kk = k + L
        for i in range(ny):
            acc = 0.0
            for j in range(n):
                acc += C[i, j] * x[j]
            for j in range(nu):
                acc += D[i, j] * u[k, j]
            Y[kk, i] = acc
        _terms_at(
            U, Y, kk, ptr, src, col, lag, diff, src2, col2, code, power, scale, offset, param,
            param2, weight, st, theta, none,
        )  # fmt: skip
        ok = True
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += A[i, j] * x[j]
            for j in range(nu):
                acc += B[i, j] * u[k, j]
            for t in range(theta.shape[0]):
                acc += E[i, t] * theta[t]
            xn[i] = acc
            if not np.isfinite(acc):
                ok = False
        x[:] = xn
        if not ok:
            Y[kk + 1 :] = np.nan
            return


@njit(cache=True, nogil=True)
def sparse_loop(  # pragma: no cover - numba
    U, X, coef, L, ptr, src, col, lag, diff, src2, col2, code, power, scale, offset, param,
    param2, weight, st,
):  # fmt: skip
    """Sparse map ``x[k+1] = θ(k)ᵀ·coef``; θ reads inputs ``U`` and states ``X`` (in place)."""
    N = U.shape[0] - L
    nx = X.shape[1]
    nt = ptr.shape[0] - 1
    theta = np.empty(nt)
    none = np.zeros(nt, dtype=np.bool_)
    for k in range(N - 1):
        kk = k + L
        _terms_at(
            U, X, kk, ptr, src, col, lag, diff, src2, col2, code, power, scale, offset, param,
            param2, weight, st, theta, none,
        )  # fmt: skip
        ok = True
        for i in range(nx):
            acc = 0.0
            for t in range(nt):
                acc += theta[t] * coef[t, i]
            X[kk + 1, i] = acc
            if not np.isfinite(acc):
                ok = False
        if not ok:
            X[kk + 1 :] = np.nan
            return


@njit(cache=True, nogil=True)
def play_loop(s, width, start):  # pragma: no cover - numba
    """Play (backlash) operator of half-width ``width`` from ``start``."""
    out = np.empty_like(s)
    v = start
    for k in range(s.shape[0]):
        x = s[k]
        if x - v > width:
            v = x - width
        elif x - v < -width:
            v = x + width
        out[k] = v
    return out


@njit(cache=True, nogil=True)
def follow_index(s, width, rate):  # pragma: no cover - numba
    """For each sample of a play (``rate`` < 0: half-width ``width``, from ``s[0]``, as
    :func:`play_loop`) or of a rate limit (``rate`` ≥ 0, as :func:`rate_loop`): the last sample
    at which its output followed ``s`` — pushed past the gap, or within the rate.  Where it
    holds (inside the gap) or slews (at the rate) the output moves with none of the later
    samples of ``s``, so its derivative with respect to anything that moves ``s`` is
    ``ds[index]``: how ``output_error.refine``'s exact Jacobian passes these blocks.
    """
    out = np.empty(s.shape[0], dtype=np.int64)
    v = s[0]
    last = 0
    for k in range(s.shape[0]):
        x = s[k]
        if rate < 0.0:
            if x - v > width:
                v = x - width
                last = k
            elif x - v < -width:
                v = x + width
                last = k
        else:
            d = x - v
            if -rate <= d <= rate:
                last = k
            v += min(max(d, -rate), rate)
        out[k] = last
    return out


@njit(cache=True, nogil=True)
def rate_loop(s, rate):  # pragma: no cover - numba
    """Follow ``s`` with at most ``rate`` change per sample, from ``s[0]``."""
    out = np.empty_like(s)
    v = s[0]
    for k in range(s.shape[0]):
        v += min(max(s[k] - v, -rate), rate)
        out[k] = v
    return out


def input_bases(flat: FlatTerms) -> tuple[NDArray[np.bool_], IntArray, FlatTerms]:
    """The terms :func:`arx_loop` takes from :func:`input_series`: ``(pre, base, factors)``.

    ``pre[t]``: term ``t`` reads inputs only (buffer 0) through memoryless functions, so its
    value at every sample is known before the recursion runs.  Its factors that differ only
    in their lag are one series, shifted (an input's powers at every lag the model reads — a
    curve between two filters has dozens): ``base[f]`` is factor ``f``'s series (-1: not
    precomputed) and ``factors`` one factor per series, as flat arrays (its ``lag`` unused).
    """
    nt, nf = flat.n_terms, flat.code.shape[0]
    term_of = np.repeat(np.arange(nt), np.diff(flat.ptr))
    memoryless_input = (flat.src == 0) & (flat.src2 <= 0) & (flat.code < PLAY)
    pre = np.bincount(term_of, weights=~memoryless_input, minlength=nt) == 0
    base = np.full(nf, -1, dtype=np.int64)
    mine = np.flatnonzero(pre[term_of])  # the factors of those terms
    # a factor's series is told by everything but its lag, compared by the bits (0.0 and -0.0
    # are different factors here); numbered in the order of their first factors
    keys = np.column_stack(
        [getattr(flat, name)[mine].astype(np.float64) for name in (
            "col", "diff", "src2", "col2", "code", "power", "scale", "offset", "param", "weight",
        )]
    ) if mine.size else np.zeros((0, 10))  # fmt: skip
    number: dict[bytes, int] = {}
    for f, key in zip(mine, keys, strict=True):
        base[f] = number.setdefault(key.tobytes(), len(number))
    idx = mine[np.unique(base[mine], return_index=True)[1]] if mine.size else mine
    factors = FlatTerms(
        np.arange(idx.shape[0] + 1, dtype=np.int64),
        *(getattr(flat, name)[idx] for name in (
            "src", "col", "lag", "diff", "src2", "col2", "code", "power", "scale", "offset",
            "param", "param2", "weight",
        )),
    )  # fmt: skip
    return pre, base, factors


@njit(cache=True, nogil=True)
def input_series(  # pragma: no cover - numba
    U, col, diff, src2, col2, code, power, scale, offset, param, weight
):  # fmt: skip
    """``(n_factors, rows)``: each factor (as :func:`input_bases` gives them) at every row of
    ``U``, computed as :func:`_terms_at` computes it (the same numbers); rows before a
    difference's reach are NaN (no lag reads them)."""
    out = np.empty((code.shape[0], U.shape[0]))
    # rows outer, factors inner (the function varies in the inner loop): a loop over one
    # function's rows could be vectorised with a vector maths library (numba uses SVML where
    # it is installed) whose sin, tanh, pow differ from the scalar calls in the last bit
    for r in range(U.shape[0]):
        for f in range(code.shape[0]):
            d = diff[f]
            if r - d < 0:
                out[f, r] = np.nan
                continue
            s = _at(U, r, col[f], d)
            if src2[f] >= 0:
                s = s - weight[f] * _at(U, r, col2[f], d)
            z = (s - offset[f]) * scale[f]
            out[f, r] = _fn(code[f], z, power[f], param[f])
    return out


def run_terms(kernel, *args, flat: FlatTerms):  # type: ignore[no-untyped-def]
    """Call ``kernel(*args, <flat terms>, <hysteresis state>)``; the state starts afresh."""
    return kernel(
        *args,
        flat.ptr,
        flat.src,
        flat.col,
        flat.lag,
        flat.diff,
        flat.src2,
        flat.col2,
        flat.code,
        flat.power,
        flat.scale,
        flat.offset,
        flat.param,
        flat.param2,
        flat.weight,
        np.full((max(flat.code.shape[0], 1), 2), np.nan),
    )


@njit(cache=True, nogil=True)
def state_loop(A, Bu, x0):  # pragma: no cover - numba
    """States ``X[k]`` of ``x⁺ = A x + Bu[k]`` from ``x0`` (the inputs' part precomputed)."""
    N, n = Bu.shape
    X = np.empty((N, n))
    x = x0.copy()
    xn = np.empty(n)
    for k in range(N):
        for i in range(n):
            X[k, i] = x[i]
        for i in range(n):
            acc = Bu[k, i]
            for j in range(n):
                acc += A[i, j] * x[j]
            xn[i] = acc
        x, xn = xn, x
    return X


@njit(cache=True, nogil=True)
def unit_response_loop(A, C, S):  # pragma: no cover - numba
    """``out`` (N, ny, nx·nc): the output of ``x⁺ = A x + e_i s_c[k]``, ``y = C x``, from rest,
    in column ``i·nc + c`` — every signal of ``S`` (N, nc) entering every state in turn."""
    N, nc = S.shape
    nx, ny = A.shape[0], C.shape[0]
    M = nx * nc
    X = np.zeros((nx, M))
    Xn = np.empty((nx, M))
    out = np.empty((N, ny, M))
    for k in range(N):
        for o in range(ny):
            for m in range(M):
                acc = 0.0
                for j in range(nx):
                    acc += C[o, j] * X[j, m]
                out[k, o, m] = acc
        for i in range(nx):
            for m in range(M):
                acc = 0.0
                for j in range(nx):
                    acc += A[i, j] * X[j, m]
                Xn[i, m] = acc
        for i in range(nx):
            for c in range(nc):
                Xn[i, i * nc + c] += S[k, c]
        X, Xn = Xn, X
    return out


@njit(cache=True, nogil=True, inline="always")
def _dfn(code: int, z: float, power: float, param: float) -> float:  # pragma: no cover - numba
    """``d _fn / d z`` almost everywhere (``tendonkit.terms._apply(..., deriv=True)``)."""
    if code == 0:
        if power == 1.0:
            return 1.0
        return power * z ** (power - 1.0)
    if code == 1:
        return np.cos(z)
    if code == 2:
        return -np.sin(z)
    if code == 3:
        t = np.tanh(z)
        return 1.0 - t * t
    if code == 4:
        return 0.0
    if code == 5:
        return 1.0 if z > 0.0 else (-1.0 if z < 0.0 else 0.0)
    if code == 6:
        return 1.0 if abs(z) > param else 0.0
    if code == 7:
        return 1.0 if abs(z) < param else 0.0
    return 1.0 if z > param else 0.0


@njit(cache=True, nogil=True, inline="always")
def _reading_tangent(S, r, c, d, P, out, w):  # pragma: no cover - numba
    """``out += w · (S[r, c] - S[r - d, c])`` (``d`` = 0: ``w · S[r, c]``) over the P columns."""
    for p in range(P):
        out[p] += w * (S[r, c, p] - S[r - d, c, p]) if d else w * S[r, c, p]


@njit(cache=True, nogil=True, inline="always")
def _linear_sensitivity(S, Phi, A, k, kk, i):  # pragma: no cover - numba
    """Row ``S[kk, i]`` set to ``Φ[k, i] - Σ_w A_w[i] S[kk-1-w]`` (the linear recursion's part
    of an ARX's sensitivities, the terms' added by the caller); returns the row."""
    row = S[kk, i]
    for p in range(S.shape[2]):
        row[p] = Phi[k, i, p]
    for w in range(A.shape[0]):
        past = S[kk - 1 - w]
        for j in range(A.shape[2]):
            a = A[w, i, j]
            if a != 0.0:
                for p in range(S.shape[2]):
                    row[p] -= a * past[j, p]
    return row


@njit(cache=True, nogil=True)
def arx_sensitivity_terms(  # pragma: no cover - numba
    Phi, A, coef, tcol, tsign, U, Y, start, L, ptr, src, col, lag, diff, src2, col2, code,
    power, scale, offset, param, param2, weight,
):  # fmt: skip
    """:func:`arx_sensitivity` for terms of every kind: operators with a memory, and terms
    whose coefficients are tied to ``A`` (a clipped state).

    The terms are evaluated along the simulation ``Y`` (padded with ``L`` rows, as
    :func:`arx_loop` wrote it; ``U`` its input buffer) from sample ``start``, as the
    simulation evaluated them, and each factor carries its tangent: ``f'(z)·∂z`` for a
    memoryless one; for an operator with a memory the tangent of its state, advanced by the
    operator's own rule in the regime it is in at that sample — a play that moves follows
    ``∂z`` and one that holds keeps its tangent, a slew lag inside its largest step is the lag
    ``(1 - g)·∂r + g·∂z`` and at it keeps its tangent, a Bouc–Wen state
    ``∂h⁺ = (1 - α|d| - β d sgn h)·∂h + (1 - α sgn(d) h - β|h|)·∂d`` with ``d = z - z⁻``.
    Term ``t``'s value adds to column ``tcol[t, i]`` of output ``i`` times ``tsign[t]`` (its
    own coefficient, or the ``A`` entry its coefficient is tied to; -1: none), so the term
    columns of ``Phi`` are left zero by the caller (its ``A``, ``B`` and offset columns hold
    their regressors).
    """
    N, ny, P = Phi.shape
    nt = ptr.shape[0] - 1
    nf = max(code.shape[0], 1)
    S = np.zeros((N + L, ny, P))
    st = np.full((nf, 2), np.nan)
    T1 = np.zeros((nf, P))  # tangent of an operator's output (Bouc-Wen: of h)
    T2 = np.zeros((nf, P))  # Bouc-Wen: tangent of the previous z
    dz = np.zeros(P)
    val = np.empty(nf)
    dv = np.zeros((nf, P))
    dth = np.zeros((nt, P))
    theta = np.empty(nt)
    moves = np.zeros(nf, dtype=np.bool_)  # reads an output: its tangent is not zero
    for f in range(code.shape[0]):
        moves[f] = src[f] == 1 or src2[f] == 1
    for k in range(start, N):
        kk = k + L
        for t in range(nt):
            for f in range(ptr[t], ptr[t + 1]):
                r, d = kk - lag[f], diff[f]
                s = _at(U, r, col[f], d) if src[f] == 0 else _at(Y, r, col[f], d)
                if src2[f] >= 0:
                    s = s - weight[f] * (
                        _at(U, r, col2[f], d) if src2[f] == 0 else _at(Y, r, col2[f], d)
                    )
                z = (s - offset[f]) * scale[f]
                for p in range(P):
                    dz[p] = 0.0
                if moves[f]:
                    if src[f] == 1:
                        _reading_tangent(S, r, col[f], d, P, dz, scale[f])
                    if src2[f] == 1:
                        _reading_tangent(S, r, col2[f], d, P, dz, -weight[f] * scale[f])
                c = code[f]
                if c < PLAY:
                    val[f] = _fn(c, z, power[f], param[f])
                    g = _dfn(c, z, power[f], param[f]) if moves[f] else 0.0
                    for p in range(P):
                        dv[f, p] = g * dz[p]
                    continue
                a, h = st[f, 0], st[f, 1]
                first = np.isnan(a)
                v = hysteresis_step(c, z, param[f], param2[f], st[f])[0]
                val[f] = v
                if c == PLAY:
                    if first or v != a:  # pushed: follows z
                        for p in range(P):
                            T1[f, p] = dz[p]
                elif c == SLEW_LAG:
                    if first:
                        for p in range(P):
                            T1[f, p] = dz[p]
                    elif abs(param[f] * (z - a)) < param2[f]:
                        g = param[f]
                        for p in range(P):
                            T1[f, p] = (1.0 - g) * T1[f, p] + g * dz[p]
                elif first:  # Bouc-Wen from h = 0
                    for p in range(P):
                        T1[f, p] = 0.0
                        T2[f, p] = dz[p]
                else:
                    dd = z - a
                    sd = 1.0 if dd > 0 else (-1.0 if dd < 0 else 0.0)
                    sh = 1.0 if h > 0 else (-1.0 if h < 0 else 0.0)
                    eh = 1.0 - param[f] * abs(dd) - param2[f] * dd * sh
                    ed = 1.0 - param[f] * sd * h - param2[f] * abs(h)
                    for p in range(P):
                        T1[f, p] = eh * T1[f, p] + ed * (dz[p] - T2[f, p])
                        T2[f, p] = dz[p]
                for p in range(P):
                    dv[f, p] = T1[f, p]
            # the term and its tangent: Σ_f ∂v_f Π_{g≠f} v_g
            prod = 1.0
            for f in range(ptr[t], ptr[t + 1]):
                prod *= val[f]
            theta[t] = prod
            for p in range(P):
                dth[t, p] = 0.0
            for f in range(ptr[t], ptr[t + 1]):
                if not moves[f]:  # reads inputs only: its tangent is zero
                    continue
                others = 1.0
                for g2 in range(ptr[t], ptr[t + 1]):
                    if g2 != f:
                        others *= val[g2]
                if others != 0.0:
                    for p in range(P):
                        dth[t, p] += others * dv[f, p]
        for i in range(ny):
            row = _linear_sensitivity(S, Phi, A, k, kk, i)
            for t in range(nt):
                q = tcol[t, i]
                if q >= 0:
                    row[q] += tsign[t] * theta[t]
                c2 = coef[t, i]
                if c2 != 0.0:
                    for p in range(P):
                        row[p] += c2 * dth[t, p]
    return S


@njit(cache=True, nogil=True)
def arx_sensitivity(Phi, A, coef, J, qcol, qlag, start, L):  # pragma: no cover - numba
    """``S`` (N + L, ny, P): sensitivities of an ARX simulation from sample ``start``.

    ``output_error.refine`` minimises the free-run simulation error of a model; its Jacobian by
    forward differences costs one simulation per parameter per iteration — for an ARX with four
    inputs, eight lags and a few dozen terms, over two hundred simulations each step.  For an ARX
    (with memoryless terms) the derivative of the simulated output with respect to every
    coefficient obeys the model's own recursion, linearised along the simulation:

        S[k] = Φ[k] - Σ_w A_w S[k-w] + Σ_t c_t Σ_q ∂θ_t/∂ŷ_q[k] S[k - lag_q]

    where ``Φ[k]`` is the regressor of each coefficient evaluated on the simulated outputs (the
    direct derivative) and the last sum runs over the terms' readings of past outputs.  One pass
    over the record gives every column at the cost of a few simulations.

    ``Phi`` (N, ny, P) the direct derivatives; ``A`` (na, ny, ny); ``coef`` (nt, ny) the term
    coefficients; ``J`` (nt, nq, N) the terms' derivatives with respect to their ``nq``
    readings of past outputs, output ``qcol[q]`` at lag ``qlag[q]``.  Rows before ``L + start``
    are zero (measured history).
    """
    N, ny, P = Phi.shape
    nt = coef.shape[0]
    nq = qcol.shape[0]
    S = np.zeros((N + L, ny, P))
    for k in range(start, N):
        kk = k + L
        for i in range(ny):
            row = _linear_sensitivity(S, Phi, A, k, kk, i)
            for t in range(nt):
                c = coef[t, i]
                if c == 0.0:
                    continue
                for q in range(nq):
                    g = c * J[t, q, k]
                    if g != 0.0:
                        past = S[kk - qlag[q]]
                        jq = qcol[q]
                        for p in range(P):
                            row[p] += g * past[jq, p]
    return S
