"""Linear regression shared by the identifiers and diagnose's extensions.

:func:`scaled_lstsq` is the least-squares solver of ARX, of ARX with terms and of the
extensions diagnose refits; :func:`term_columns` evaluates structured terms
(:mod:`tendonkit.terms`) on a dataset as regressor columns.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .dataset import Dataset, Experiment
from .terms import CompiledTerms, Factor, Getter, Term, series_getter

__all__ = ["r_factor", "scaled_lstsq", "term_columns", "term_columns_of"]

FloatArray = NDArray[np.float64]


def scaled_lstsq(Phi: FloatArray, Y: FloatArray, ridge: float = 0.0) -> FloatArray:
    """Least squares with unit-norm column scaling and optional ridge.

    The tall problem is reduced by a blocked Householder QR of ``[Phi | Y]`` (LAPACK geqrf,
    orthogonal, so no squaring of the condition number as with normal equations); the small
    triangular problem is then solved by a rank-revealing SVD solver, which also handles
    exactly collinear regressors.
    """
    # lazy: heavy (scipy)
    from scipy.linalg import lstsq

    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(Y))):
        # LAPACK would print to stdout and return garbage; a caller trying candidates skips it
        raise ValueError("the regressors or targets are not finite (a diverged signal).")
    with np.errstate(over="ignore"):
        # a column beyond ~1e154 (a high power of a large signal) has an infinite norm: it is
        # scaled to zero and its coefficient is 0, as for an exactly collinear column
        scale = np.linalg.norm(Phi, axis=0)
    scale[scale == 0] = 1.0
    P = Phi / scale
    k = P.shape[1]
    if ridge > 0:
        P = np.vstack([P, np.sqrt(ridge) * np.eye(k)])
        Y = np.vstack([Y, np.zeros((k, Y.shape[1]))])
    if P.shape[0] > 4 * (k + Y.shape[1]):
        R = r_factor(np.hstack([P, Y]))
        m = min(R.shape[0], k)
        P, Y = R[:m, :k], R[:m, k:]
    theta, *_ = lstsq(P, Y, check_finite=False, cond=1e-13)
    return np.asarray(theta / scale[:, None])


#: Rows per block of the tall QR (a block of ~50 columns stays in cache).
QR_BLOCK = 2048


def _householder_r(A: FloatArray) -> FloatArray:
    """The ``(min(n, c), c)`` triangular factor of ``A`` by LAPACK's Householder ``geqrf``.

    Called directly: ``scipy.linalg.qr(mode="r")`` adds a workspace query, a copy and the
    extraction of the full ``(n, c)`` factor, 1.5-2x the cost of the factorisation itself on
    the regressions of an ARX (benchmarks/bench_lstsq.py; benchmarks/README.md, "The tall QR
    under every least-squares fit").
    """
    # lazy: heavy (scipy)
    from scipy.linalg import get_lapack_funcs

    if A.shape[0] == 0:
        return np.zeros((0, A.shape[1]), dtype=A.dtype)
    (geqrf,) = get_lapack_funcs(("geqrf",), (A,))
    qr, _, _, info = geqrf(A)
    if info != 0:  # pragma: no cover - only for invalid arguments
        raise ValueError(f"LAPACK geqrf failed (info {info}).")
    return np.triu(qr[: min(A.shape)])


def r_factor(A: FloatArray) -> FloatArray:
    """The triangular factor of ``A``'s QR, by blocks of rows (TSQR) when ``A`` is tall.

    Householder QR of a tall matrix streams the whole matrix through memory once per column;
    factoring blocks of :data:`QR_BLOCK` rows that fit in cache and then the stacked block
    factors gives the same ``R`` (up to the signs of its rows, which least squares ignore) with
    the same orthogonal-transformation accuracy, several times faster on 10⁵ rows.
    """
    n, c = A.shape
    block = max(QR_BLOCK, 4 * c)
    if n <= 2 * block:
        return _householder_r(A)
    parts = [_householder_r(A[i : i + block]) for i in range(0, n, block)]
    return _householder_r(np.vstack(parts))


def term_columns_of(terms: Sequence[Term], signals: dict[str, FloatArray], n: int) -> FloatArray:
    """``(n, n_terms)`` values of ``terms`` on named signal series (constants when no signal).

    Without operators with a memory, each distinct factor is evaluated once at lag 0 and
    shifted to every lag it is read at (:func:`_shifted_columns`): the same numbers, at a
    fraction of the cost for the powers of an input at every lag a model reads.
    """
    ct = CompiledTerms(terms)
    if not ct.keys:
        return np.ones((n, ct.n_terms))
    get = series_getter(signals)
    if not ct.stateful:
        return _shifted_columns(ct.terms, get, n)
    return ct.evaluate(np.array([get(name, lag) for name, lag in ct.keys])).T


def _shifted_columns(terms: Sequence[Term], get: Getter, n: int) -> FloatArray:
    """:func:`term_columns_of` for memoryless terms, each distinct factor evaluated once.

    A factor read at lag ``l`` is the factor at lag 0 shifted by ``l`` samples, its first
    ``l`` samples the first sample's value — exactly what evaluating it on the edge-padded
    lagged series (:func:`tendonkit.terms.series_getter`) gives, element by element; a term
    is the product of its factors in order, as :meth:`CompiledTerms.evaluate` forms it.
    """
    at_zero = [[dataclasses.replace(f, lag=0) for f in t.factors] for t in terms]
    index: dict[Factor, int] = {}
    for fs in at_zero:
        for f in fs:
            index.setdefault(f, len(index))
    if index:
        ct = CompiledTerms([Term((f,)) for f in index])
        values = ct.evaluate(np.array([get(name, lag) for name, lag in ct.keys]))
    out = np.ones((len(terms), n))  # returned transposed, the memory layout evaluate's has
    for t, (term, fs) in enumerate(zip(terms, at_zero, strict=True)):
        for j, (f, f0) in enumerate(zip(term.factors, fs, strict=True)):
            v = values[index[f0]]
            lag = min(f.lag, n)
            if j == 0:
                out[t, lag:] = v[: n - lag]
                out[t, :lag] = v[0] if n else 1.0
            else:
                out[t, lag:] *= v[: n - lag]
                out[t, :lag] *= v[0] if n else 1.0
    return out.T


def term_columns(terms: Sequence[Term], e: Experiment, data: Dataset) -> FloatArray:
    """``(n, n_terms)`` values of ``terms`` on experiment ``e`` of ``data`` (signals by name)."""
    signals = {
        **{n: e.u[:, j] for j, n in enumerate(data.inputs)},
        **{n: e.y[:, j] for j, n in enumerate(data.outputs)},
    }
    return term_columns_of(terms, signals, e.n_samples)
