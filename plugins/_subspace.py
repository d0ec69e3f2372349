"""Numerics of the N4SID identifier: Hankel Gram matrix, LQ factor, subspace step, B/D/x0 fit.

Everything here works on plain arrays; :mod:`tendonkit.plugins.n4sid` wraps it into the plugin.
Memory is linear in the number of samples: the block-Hankel matrix is never formed (its Gram
matrix is built from lagged products of the signals), and the simulation-error least squares
runs over time chunks and never forms its regressor matrix.

References
----------
P. Van Overschee and B. De Moor, *Subspace Identification for Linear Systems*, Kluwer 1996,
§4.3 (robust combined algorithm, Fig. 4.8) and the authors' ``subid.m``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import linalg

FloatArray = NDArray[np.float64]

#: Time samples per chunk in the simulation-error least squares (bounds the memory); rounded
#: down to whole blocks.
CHUNK = 4096
#: Samples per block in the simulation-error least squares: the dual states are computed at
#: block starts only, and the regressors within a block follow from them by fixed matrices.
BLOCK = 16
#: Steps per group in the nested-group recursion of the block-start states.
GROUP = 8
#: Relative magnitude below which decaying responses are set to zero (avoids subnormals).
TINY = 1e-100
#: Entries of ``Σ_r Ψ ⊗ Ψ`` formed at once in the least squares (bounds the memory, 8 MB).
G_ENTRIES = 1 << 20


# -- block-Hankel Gram matrix and its LQ factor -------------------------------------------------


def hankel_gram(z: FloatArray, s: int) -> FloatArray:
    """Gram matrix ``H Hᵀ`` of the block-Hankel matrix of ``z`` with ``s`` block rows.

    ``H[(a, c), t] = z[t + a, c]`` for ``a < s`` and ``t < N - s + 1``; the result is indexed
    ``[(a, c), (b, d)]`` (block row major).  It is computed from the ``s`` lagged products
    ``Σ_t z[t]ᵀ z[t + d]`` over the whole record, corrected for the few samples each block row
    does not see, so the cost is ``O(N s m²)`` and the memory ``O(N m)``: the ``(s m) × N``
    matrix ``H`` is never formed.  The lagged products come from two matrix products of the
    record folded into rows of ``s`` samples (a view, no copy): row ``q`` with itself gives
    the pairs of samples within a row, row ``q`` with row ``q + 1`` the pairs across rows.

    Parameters
    ----------
    z : array (N, m)
        Signals (inputs and outputs side by side).
    s : int
        Number of block rows (``2 i`` for past and future horizons of ``i``).

    Returns
    -------
    array (s m, s m)
        The symmetric Gram matrix.
    """
    N, m = z.shape
    j = N - s + 1
    # lag products full[d] = Σ_{t < N-d} z[t] z[t+d]ᵀ from the folded record
    nq = N // s
    rows = np.ascontiguousarray(z[: nq * s]).reshape(nq, s * m)
    last = np.zeros(s * m)  # the incomplete last row, zero-padded
    last[: (N - nq * s) * m] = z[nq * s :].ravel()
    same = rows.T @ rows + np.outer(last, last)  # [(a, c), (b, d)]: Σ_q z[qs+a, c] z[qs+b, d]
    cross = rows[:-1].T @ rows[1:]  # Σ_q z[qs+a] z[(q+1)s+b]ᵀ, pairs across rows
    if nq:
        cross += np.outer(rows[-1], last)
    same4, cross4 = same.reshape(s, m, s, m), cross.reshape(s, m, s, m)
    full = np.empty((s, m, m))
    for lag in range(s):
        r = np.arange(s - lag)
        full[lag] = same4[r, :, r + lag, :].sum(axis=0)
        if lag:
            r = np.arange(s - lag, s)
            full[lag] += cross4[r, :, r + lag - s, :].sum(axis=0)
    # block (a, a+d) sums t over [a, a + j): remove the head t < a and the tail t >= a + j,
    # from the outer products of the first and of the last s - 1 samples.
    head = np.zeros((s, s, m, m))  # Σ_{t < a}
    np.cumsum(_lag_outers(z[: s - 1], s)[:-1], axis=0, out=head[1:])
    tail = np.cumsum(_lag_outers(z[j:], s)[::-1], axis=0)[::-1]  # Σ_{t >= a} over t - j
    a, d = np.nonzero(np.add.outer(np.arange(s), np.arange(s)) < s)
    blk = full[d] - head[a, d] - tail[a, d]
    G = np.empty((s, m, s, m))
    G[a, :, a + d, :] = blk
    G[a + d, :, a, :] = blk.transpose(0, 2, 1)
    return G.reshape(s * m, s * m)


def _lag_outers(seg: FloatArray, s: int) -> FloatArray:
    """``O[t, d] = seg[t] seg[t+d]ᵀ`` for ``t, d < s``, zero where ``t + d`` is past the end."""
    m = seg.shape[1]
    pad = np.zeros((2 * s, m))
    pad[: seg.shape[0]] = seg
    lagged = np.lib.stride_tricks.sliding_window_view(pad, s, axis=0)[:s]  # [t, c, d]
    return np.einsum("tc,tkd->tdck", pad[:s], lagged)


def lq_factor(gram: FloatArray) -> FloatArray:
    """Lower-triangular ``L`` with ``L Lᵀ = gram`` (the L of the data matrix's LQ factorisation).

    A Cholesky factorisation of the Gram matrix.  Noise-free data make the Gram matrix
    singular (future outputs are exact combinations of past data and future inputs); a
    diagonal shift of ``1e-14`` of its largest entry, increased tenfold until the factorisation
    succeeds, plays the role of the rounding errors a QR factorisation would produce.  The
    signal subspace is unaffected: noise-free systems are still recovered to ~1e-12.
    """
    scale = float(np.max(np.diag(gram)))
    if not np.isfinite(scale) or scale <= 0:
        return np.zeros_like(gram)
    eye = np.eye(gram.shape[0])
    shift = 0.0
    for _ in range(12):
        try:
            return np.asarray(linalg.cholesky(gram + shift * eye, lower=True, check_finite=False))
        except linalg.LinAlgError:
            shift = scale * 1e-14 if shift == 0 else shift * 10
    raise linalg.LinAlgError("the data Gram matrix is not positive semi-definite")


# -- subspace step ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Subspace:
    """Result of the subspace step in scaled units.

    ``A``, ``C`` and the innovation covariances ``Q``, ``S``, ``R`` (per sample) of the model in
    the coordinates of the scaled data; ``singular_values`` of the weighted oblique projection.
    """

    A: FloatArray
    C: FloatArray
    Q: FloatArray
    S: FloatArray
    R: FloatArray
    singular_values: FloatArray


def _proj_perp(X: FloatArray, Ru: FloatArray) -> FloatArray:
    """``X`` minus its projection on the row space of ``Ru`` (first ``Ru.shape[1]`` columns)."""
    k = Ru.shape[1]
    coef = linalg.lstsq(Ru.T, X[:, :k].T, check_finite=False, lapack_driver="gelsy")[0].T
    out = X.copy()
    out[:, :k] -= coef @ Ru
    return out


def _rdivide(X: FloatArray, Y: FloatArray) -> FloatArray:
    """Least-squares ``X / Y`` (Matlab's right division): ``argmin ||θ Y − X||``."""
    return np.asarray(linalg.lstsq(Y.T, X.T, check_finite=False, lapack_driver="gelsd")[0].T)


def singular_values_and_basis(
    L: FloatArray, nu: int, ny: int, i: int
) -> tuple[FloatArray, FloatArray]:
    """Left singular vectors and singular values of the weighted oblique projection.

    Rows of ``L`` are ordered ``[U_past; U_future; Y_past; Y_future]``, each ``i`` block rows.
    The oblique projection of the future outputs along the future inputs on the past data is
    weighted on the right by the projection orthogonal to the future inputs (the "robust"
    weighting of Van Overschee & De Moor), whose column space is the extended observability
    matrix.
    """
    mi, li = nu * i, ny * i
    Rf = L[2 * mi + li :]
    Rp = np.vstack([L[:mi], L[2 * mi : 2 * mi + li]])
    Ru = L[mi : 2 * mi, : 2 * mi]
    if nu:
        Rfp = _proj_perp(Rf, Ru)
        Rpp = _proj_perp(Rp, Ru)
    else:
        Rfp, Rpp = Rf, Rp
    Ob = _rdivide(Rfp, Rpp) @ Rp
    WOW = _proj_perp(Ob, Ru) if nu else Ob
    U, s, _ = linalg.svd(WOW, full_matrices=False, check_finite=False)
    return U, s


def select_order(s: FloatArray, max_order: int) -> int:
    """Order at the largest gap of the log singular values, among ``1..max_order``.

    Singular values below ``1e-12`` of the largest are treated as that floor, so the gaps
    between rounding-level values of noise-free data never win.
    """
    if s.size == 0 or s[0] <= 0:
        return 1
    floor = s[0] * 1e-12
    logs = np.log10(np.maximum(s[: max_order + 1], floor))
    if logs.size < 2:
        return 1
    gaps = logs[:-1] - logs[1:]
    return int(np.argmax(gaps[:max_order])) + 1


def system_matrices(
    L: FloatArray, U: FloatArray, s: FloatArray, nu: int, ny: int, i: int, n: int
) -> Subspace:
    """``A``, ``C`` and noise covariances from the LQ factor and the observability basis.

    The Kalman-filter state sequences ``X_i = Γ_i⁺ Z_i`` and ``X_{i+1} = Γ_{i-1}⁺ Z_{i+1}`` are
    handled through their coefficients in ``L`` (no ``N``-long array), and
    ``[X_{i+1}; Y_{i|i}] = [A; C] X_i + (terms in the future inputs) + residuals`` is solved
    by least squares (Van Overschee & De Moor, Fig. 4.8); the residual covariance gives
    ``Q``, ``S``, ``R``.
    """
    mi, li = nu * i, ny * i
    gam = U[:, :n] * np.sqrt(s[:n])
    gamm = gam[: li - ny]
    gam_inv = linalg.pinv(gam)
    gamm_inv = linalg.pinv(gamm)
    yf = 2 * mi + li  # first row of the future outputs
    w = yf + ny
    top = np.hstack([gam_inv @ L[yf:, :yf], np.zeros((n, ny))])
    Rhs = np.vstack([top, L[mi : 2 * mi, :w]])
    Lhs = np.vstack([gamm_inv @ L[yf + ny :, :w], L[yf : yf + ny, :w]])
    sol = _rdivide(Lhs, Rhs)
    res = Lhs - sol @ Rhs
    cov = res @ res.T
    cov = 0.5 * (cov + cov.T)
    return Subspace(
        A=sol[:n, :n].copy(),
        C=sol[n:, :n].copy(),
        Q=cov[:n, :n],
        S=cov[:n, n:],
        R=cov[n:, n:],
        singular_values=s,
    )


def subspace_input_matrices(
    L: FloatArray, A: FloatArray, C: FloatArray, nu: int, ny: int, i: int
) -> tuple[FloatArray, FloatArray]:
    """``B`` and ``D`` (scaled units) of the combined algorithm, for given ``A`` and ``C``.

    The future-input terms of the state least squares are linear in ``B`` and ``D``; with
    ``Γ_i`` rebuilt from ``A`` and ``C`` they are fitted by one Kronecker-structured least
    squares problem (Van Overschee & De Moor 1996, §4.3.2, and ``subid.m``).  Used when ``A``
    is unstable and may not be stabilised, so that the simulation error of a long record
    cannot be minimised.
    """
    n = A.shape[0]
    if nu == 0:
        return np.zeros((n, 0)), np.zeros((ny, 0))
    mi, li = nu * i, ny * i
    gam = np.empty((li, n))
    gam[:ny] = C
    for k in range(1, i):
        gam[k * ny : (k + 1) * ny] = gam[(k - 1) * ny : k * ny] @ A
    gamm = gam[: li - ny]
    gam_inv, gamm_inv = linalg.pinv(gam), linalg.pinv(gamm)
    yf = 2 * mi + li
    w = yf + ny
    Rhs_x = gam_inv @ L[yf:, :w]  # the states' coefficients (zero in the last ny columns)
    Rhs_x[:, yf:] = 0.0
    Lhs = np.vstack([gamm_inv @ L[yf + ny :, :w], L[yf : yf + ny, :w]])
    P = (Lhs - np.vstack([A, C]) @ Rhs_x)[:, : 2 * mi]
    Q = L[mi : 2 * mi, : 2 * mi]
    L1, L2 = A @ gam_inv, C @ gam_inv
    M = np.hstack([np.zeros((n, ny)), gamm_inv])
    X = np.zeros((li, ny + n))
    X[:ny, :ny] = np.eye(ny)
    X[ny:, ny:] = gamm
    tot = np.zeros((2 * mi * (n + ny), nu * (ny + n)))
    for k in range(i):
        Nk = np.zeros((n + ny, li))
        Nk[:n, : li - k * ny] = M[:, k * ny :] - L1[:, k * ny :]
        Nk[n:, : li - k * ny] = -L2[:, k * ny :]
        if k == 0:
            Nk[n:, :ny] += np.eye(ny)
        tot += np.kron(Q[k * nu : (k + 1) * nu].T, Nk @ X)
    sol = linalg.lstsq(tot, P.reshape(-1, order="F"), check_finite=False)[0]
    DB = sol.reshape(ny + n, nu, order="F")
    return DB[ny:], DB[:ny]


# -- stability and Kalman gain ---------------------------------------------------------------------


def spectral_radius(A: FloatArray) -> float:
    """Largest eigenvalue modulus."""
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def stabilize(A: FloatArray, radius: float) -> FloatArray:
    """Reflect eigenvalues outside the unit circle inside it (``λ → λ / |λ|²``), capped at ``radius``.

    The reflection keeps the frequency of every mode and the magnitude of its frequency
    response up to a constant, which the following ``B``/``D`` fit absorbs.  Eigenvalues
    already inside ``radius`` are unchanged.
    """
    lam, V = np.linalg.eig(A)
    mag = np.abs(lam)
    bad = mag >= radius
    if not bad.any():
        return A
    new = lam.copy()
    new[bad] = lam[bad] / mag[bad] * np.minimum(1.0 / mag[bad], radius)
    if np.linalg.cond(V) > 1e10:  # (nearly) defective: scale the whole matrix instead
        return np.asarray(A * (radius / float(np.max(mag))))
    return np.asarray(np.real(V @ np.diag(new) @ np.linalg.inv(V)))


def kalman_gain(sub: Subspace, A: FloatArray) -> FloatArray | None:
    """Innovation gain from the residual covariances (forward Riccati equation), or None."""
    n = A.shape[0]
    Q, S, R = sub.Q, sub.S, sub.R
    if not np.all(np.isfinite(R)) or np.linalg.cond(R) > 1e12:
        return None
    try:
        P = linalg.solve_discrete_are(A.T, sub.C.T, Q + 1e-12 * np.trace(Q) * np.eye(n), R, s=S)
        K = (A @ P @ sub.C.T + S) @ np.linalg.inv(sub.C @ P @ sub.C.T + R)
    except (np.linalg.LinAlgError, ValueError):
        return None
    if not np.all(np.isfinite(K)) or spectral_radius(A - K @ sub.C) >= 1.0:
        return None
    return np.asarray(K)


# -- B, D and x0 by least squares on the simulation error ------------------------------------------


def _flush(x: FloatArray, scale: float | None = None) -> FloatArray:
    """Set the entries of ``x`` below ``TINY · scale`` in magnitude to zero (in place).

    ``scale`` defaults to the sum of magnitudes of each column (last axis) of ``x``, so signals
    of different sizes are flushed independently.  Decaying responses would otherwise reach
    the subnormal range, where every product slows down by orders of magnitude; the values
    change by less than about ``TINY`` relative.
    """
    mag = np.abs(x)
    if scale is None:
        flat = mag.reshape(-1, mag.shape[-1])
        small = mag < TINY * (np.ones(flat.shape[0]) @ flat)
    else:
        small = mag < TINY * scale
    if small.any():
        np.copyto(x, 0.0, where=small)
    return x


def _powers(F: FloatArray, k: int) -> FloatArray:
    """``F⁰ … Fᵏ`` as one ``(k + 1, n, n)`` array, flushed (see :func:`_flush`)."""
    out = np.empty((k + 1, *F.shape))
    out[0] = np.eye(F.shape[0])
    for r in range(1, k + 1):
        out[r] = _flush(F @ out[r - 1], 1.0)
    return out


class _Recursion:
    """States of ``x[k+1] = F x[k] + e[k]`` for many steps at once, by nested groups of steps.

    Within a group of ``g`` steps the states are one product with the lower block-triangular
    Toeplitz matrix of ``F⁰ … F^(g-1)``, plus the free response of the group's first state;
    the groups' first states obey the same recursion with ``F^g``, which the next level solves.
    No Python loop runs over the steps, and no power above ``F^g`` of one level is formed.
    The states of every level are flushed column by column (see :func:`_flush`).
    """

    def __init__(self, F: FloatArray, group: int = GROUP) -> None:
        self.group = group
        self._F = [F]
        self._tables: list[tuple[FloatArray, FloatArray]] = []

    def _table(self, level: int) -> tuple[FloatArray, FloatArray]:
        """``F_level⁰ … F_level^g`` and the ``((g+1) n, g n)`` Toeplitz matrix of one group."""
        while len(self._tables) <= level:
            F, g = self._F[-1], self.group
            n = F.shape[0]
            powers = _powers(F, g)
            T = np.zeros((g + 1, n, g, n))  # T[r, :, s] = F^(r-1-s) for s < r
            for r in range(1, g + 1):
                T[r, :, :r] = powers[r - 1 :: -1].transpose(1, 0, 2)
            self._tables.append((powers, T.reshape((g + 1) * n, g * n)))
            self._F.append(powers[g])
        return self._tables[level]

    def run(self, E: FloatArray, x0: FloatArray, level: int = 0) -> FloatArray:
        """States ``x[0] … x[K]``, shape ``(K + 1, n, q)``, for inputs ``E`` of shape ``(K, n, q)``."""
        K, n, q = E.shape
        g = self.group
        powers, T = self._table(level)
        ng = max(1, -(-K // g))
        if ng * g != K:
            E = np.concatenate([E, np.zeros((ng * g - K, n, q))])
        Eg = E.reshape(ng, g, n, q).transpose(1, 2, 0, 3).reshape(g * n, ng * q)
        forced = (T @ Eg).reshape(g + 1, n, ng, q)  # [r, i, group, :]
        if ng == 1:
            starts = np.stack([x0, powers[g] @ x0 + forced[g, :, 0]])
        else:
            starts = self.run(forced[g].transpose(1, 0, 2), x0, level + 1)
        X = np.empty((ng * g + 1, n, q))
        free = powers[:g].reshape(g * n, n) @ starts[:ng].transpose(1, 0, 2).reshape(n, ng * q)
        inner = X[:-1].reshape(ng, g, n, q).transpose(1, 2, 0, 3)
        np.add(free.reshape(g, n, ng, q), forced[:g], out=inner)
        X[-1] = starts[ng]
        return _flush(X[: K + 1])


class _BlockRegressors:
    """Normal equations of the simulation-error least squares of one record, block by block.

    For output ``p`` and sample ``k = bL + r`` (block ``b`` of ``L = BLOCK`` samples) all
    regressors are the entries of the ``(n+1) × (nu+1)`` matrix ``Ω = Ψ_pr Z_bp`` with::

        Ψ_pr = [[(Aᵀ)ʳ, T_pr], [0, e_rᵀ]],    Z_bp = [[W_bp, v_bp], [U_b, 0]]

    where ``W_bp`` (n × nu) holds the dual states ``w_pj`` at the block start, ``v_bp = (Aᵀ)^(bL)
    c_p``, ``U_b`` (L × nu) the block's inputs, and ``T_pr[:, s] = (Aᵀ)^(r-1-s) c_p`` for
    ``s < r`` (zero otherwise).  ``Ω[:n, :nu]`` are the ``B`` regressors ``w_pj[k]``,
    ``Ω[:n, nu]`` the ``x0`` regressors ``(Aᵀ)ᵏ c_p`` and ``Ω[n, :nu]`` the ``D`` regressors
    ``u[k]``.  So ``Σ_br Ω ⊗ Ω = (Σ_r Ψ_pr ⊗ Ψ_pr) (Σ_b Z_bp ⊗ Z_bp)``: the samples enter
    only through the Gram matrix of one short row per block and output (block-start states,
    the block's inputs and outputs), and the ``N ny × n nu`` regressor matrix is never formed.
    The block-start states come from :class:`_Recursion` with ``(Aᵀ)^L``.
    """

    def __init__(self, A: FloatArray, C: FloatArray, nu: int, block: int = BLOCK) -> None:
        n, ny, L = A.shape[0], C.shape[0], block
        self.n, self.ny, self.nu, self.block, self.C = n, ny, nu, L, C
        P = _powers(A.T, L)
        imp = P[:L] @ C.T  # (Aᵀ)ʳ Cᵀ: (L, n, ny)
        m1, m2, w = n + 1, n + L, nu + 1
        Psi = np.zeros((ny, L, m1, m2))
        Psi[:, :, :n, :n] = P[:L]
        for r in range(1, L):
            Psi[:, r, :n, n : n + r] = imp[r - 1 :: -1].transpose(2, 1, 0)
        Psi[:, np.arange(L), n, n + np.arange(L)] = 1.0
        self.Psi = Psi
        self.Pt = np.ascontiguousarray(Psi.transpose(0, 2, 3, 1))  # [p, i, a, r]
        self._G: dict[int, FloatArray] = {}
        self.PsiT = Psi.transpose(0, 1, 3, 2).reshape(ny, L * m2, m1)  # [(r, a), i]
        # block-end forced dual states: E[b, i, p, j] = Σ_s (Aᵀ)^(L-1-s) c_p u[bL + s, j]
        Kend = np.zeros((L, nu, n, ny, w))
        Kend[:, np.arange(nu), :, :, np.arange(nu)] = imp[::-1]
        self.Kend = Kend.reshape(L * nu, n * ny * w)
        self.rec = _Recursion(P[L])
        # one row per block and output: [states (n, nu+1), inputs (L, nu), outputs (L), 0]
        self.uoff, self.yoff, self.width = n * w, n * w + L * nu, n * w + L * nu + L + 1
        ia, ja = np.arange(m2)[:, None], np.arange(w)[None, :]
        self.Ia = np.where(  # column of Z_bp[a, j] in the row
            ia < n,
            np.minimum(ia, n - 1) * w + ja,
            np.where(ja < nu, self.uoff + (ia - n) * nu + ja, self.width - 1),
        )

    def _weights(self, p: int, i0: int, i1: int) -> FloatArray:
        """Rows ``i0 <= i < i1`` of ``G_p = Σ_r Ψ_pr ⊗ Ψ_pr``, indexed ``[(i, i'), (a, a')]``.

        The whole matrix is kept for the next experiment; when it has more than
        ``G_ENTRIES`` entries it is formed a few rows at a time and not kept.
        """
        whole = i0 == 0 and i1 == self.n + 1
        if whole and p in self._G:
            return self._G[p]
        Pt = self.Pt[p]
        G = np.matmul(Pt[i0:i1, None], Pt[None].swapaxes(-1, -2))  # [i, i', a, a']
        G = G.reshape((i1 - i0) * Pt.shape[0], -1)
        if whole:
            self._G[p] = G
        return G

    def normal_equations(
        self, u: FloatArray, y: FloatArray, with_x0: bool
    ) -> tuple[FloatArray, FloatArray]:
        """``Σ Ω ⊗ Ω`` and ``Σ Ω y_p`` per output: shapes ``(ny, m, m)`` and ``(ny, m)``.

        ``m = (n+1)(nu+1)`` indexes ``Ω`` row-major.  The record is processed ``CHUNK``
        samples at a time; the last incomplete block is added sample by sample.
        """
        n, ny, nu, L = self.n, self.ny, self.nu, self.block
        m1, m2, w = n + 1, n + L, nu + 1
        N = u.shape[0]
        state = np.zeros((n, ny, w))
        if with_x0:
            state[:, :, nu] = self.C.T
        n_blocks = N // L
        per = max(1, CHUNK // L)
        rows = np.zeros((min(per, n_blocks), self.width))  # the last column stays zero
        Xi = np.zeros((ny, self.width, self.width))
        uoff, yoff = self.uoff, self.yoff
        for b0 in range(0, n_blocks, per):
            nb = min(per, n_blocks - b0)
            k0, k1 = b0 * L, (b0 + nb) * L
            ub = u[k0:k1].reshape(nb, L * nu)
            E = (ub @ self.Kend).reshape(nb, n, ny * w)
            X = self.rec.run(E, state.reshape(n, ny * w)).reshape(nb + 1, n, ny, w)
            Z = rows[:nb]
            Z[:, uoff:yoff] = ub
            for p in range(ny):
                Z[:, :uoff] = X[:nb, :, p].reshape(nb, uoff)
                Z[:, yoff:-1] = y[k0:k1, p].reshape(nb, L)
                Xi[p] += Z.T @ Z  # a symmetric rank-k update (BLAS syrk)
            state = X[nb]
        gram = np.empty((ny, m1 * w, m1 * w))
        cross = np.empty((ny, m1 * w))
        step = max(1, G_ENTRIES // (m1 * m2 * m2))  # rows i of G_p per product
        g = np.empty((m1, m1, w, w))
        for p in range(ny):
            # Σ_br Ω[i, j] Ω[i', j'] = Σ_aa' G_p[i, i', a, a'] Y[a, a', j, j']
            col = self.Ia
            Y = Xi[p][col[:, None, :, None], col[None, :, None, :]]  # Σ_b Z[a, j] Z[a', j']
            Y = Y.reshape(m2 * m2, w * w)
            for i0 in range(0, m1, step):
                G = self._weights(p, i0, min(m1, i0 + step))
                g[i0 : i0 + step] = (G @ Y).reshape(-1, m1, w, w)
            gram[p] = g.transpose(0, 2, 1, 3).reshape(m1 * w, m1 * w)
            K = Xi[p][yoff : yoff + L, col]  # Σ_b y_p[bL + r] Z[a, j]: [r, a, j]
            cross[p] = (K.reshape(L * m2, w).T @ self.PsiT[p]).T.reshape(-1)
        k0 = n_blocks * L
        if k0 < N:  # incomplete last block: its regressors directly
            Z = np.zeros((m2, w))
            Z[n : n + N - k0, :nu] = u[k0:]
            for p in range(ny):
                Z[:n] = state[:, p]
                Om = (self.Psi[p, : N - k0] @ Z).reshape(N - k0, m1 * w)
                gram[p] += Om.T @ Om
                cross[p] += Om.T @ y[k0:, p]
        return gram, cross


def fit_input_matrices(
    A: FloatArray,
    C: FloatArray,
    experiments: Sequence[tuple[FloatArray, FloatArray]],
    *,
    feedthrough: bool,
    estimate_x0: bool,
) -> tuple[FloatArray, FloatArray, list[FloatArray]]:
    """``B``, ``D`` and one initial state per experiment minimising the simulation error.

    With ``A`` and ``C`` fixed the simulated output is linear in ``B``, ``D`` and ``x0``:
    ``y_p[k] = Σ_j w_pj[k]ᵀ b_j + Σ_j D_pj u_j[k] + v_p[k]ᵀ x0`` where ``w_pj`` is the state of
    the dual system ``w[k+1] = Aᵀ w[k] + c_p u_j[k]`` (``w[0] = 0``) and ``v_p[k] = (Aᵀ)ᵏ c_p``.
    The normal equations are accumulated block by block (:class:`_BlockRegressors`; memory
    independent of the record length), equilibrated and solved by a rank-revealing (SVD)
    least-squares solver.

    Parameters
    ----------
    A, C : arrays
        State and output matrices (``A`` stable for long records).
    experiments : sequence of (u, y)
        Records ``u`` (N, nu) and ``y`` (N, ny).
    feedthrough : bool
        Estimate ``D`` (otherwise it is zero).
    estimate_x0 : bool
        Estimate one initial state per experiment (otherwise zero).

    Returns
    -------
    B, D, x0s
        ``B`` (n, nu), ``D`` (ny, nu) and the initial state of every experiment.
    """
    n, ny = A.shape[0], C.shape[0]
    nu = experiments[0][0].shape[1]
    nB, nD = n * nu, (ny * nu if feedthrough else 0)
    n_shared = nB + nD
    nx = n if estimate_x0 else 0
    n_par = n_shared + nx * len(experiments)
    M = np.zeros((n_par, n_par))
    rhs = np.zeros(n_par)
    reg = _BlockRegressors(A, C, nu)
    for e, (u, y) in enumerate(experiments):
        gram, cross = reg.normal_equations(
            np.ascontiguousarray(u, dtype=float), np.ascontiguousarray(y, dtype=float), bool(nx)
        )
        for p in range(ny):
            # parameter of every entry of Ω: B[i, j] at j n + i, x0_i, D[p, j]; -1 for none
            pos = np.full((n + 1, nu + 1), -1)
            pos[:n, :nu] = np.arange(nu)[None, :] * n + np.arange(n)[:, None]
            if nx:
                pos[:n, nu] = n_shared + nx * e + np.arange(n)
            if nD:
                pos[n, :nu] = nB + p * nu + np.arange(nu)
            keep = pos.ravel() >= 0
            idx = pos.ravel()[keep]
            M[np.ix_(idx, idx)] += gram[p][np.ix_(keep, keep)]
            rhs[idx] += cross[p][keep]
    d = np.sqrt(np.diag(M))
    d[d == 0] = 1.0
    theta = linalg.lstsq(M / d[:, None] / d[None, :], rhs / d, check_finite=False, cond=1e-13)[0]
    theta = theta / d
    B = theta[:nB].reshape(nu, n).T.copy()
    D = theta[nB:n_shared].reshape(ny, nu).copy() if nD else np.zeros((ny, nu))
    x0s = [
        theta[n_shared + nx * e : n_shared + nx * (e + 1)].copy() if nx else np.zeros(n)
        for e in range(len(experiments))
    ]
    return B, D, x0s
