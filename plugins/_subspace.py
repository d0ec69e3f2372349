"""Numerics of the N4SID identifier: Hankel Gram matrix, LQ factor, subspace step, B/D/x0 fit.

Everything here works on plain arrays; :mod:`tendonkit.plugins.n4sid` wraps it into the plugin.
Memory is linear in the number of samples: the block-Hankel matrix is never formed (its Gram
matrix is built from lagged products of the signals), and the simulation-error least squares
runs over time chunks.

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

#: Time samples per chunk in the simulation-error least squares (bounds the memory).
CHUNK = 8192
#: Block length of the block-recursive simulation (state recursion runs once per block);
#: ``CHUNK`` must be a multiple of it.
BLOCK = 32


# -- block-Hankel Gram matrix and its LQ factor -------------------------------------------------


def hankel_gram(z: FloatArray, s: int) -> FloatArray:
    """Gram matrix ``H Hᵀ`` of the block-Hankel matrix of ``z`` with ``s`` block rows.

    ``H[(a, c), t] = z[t + a, c]`` for ``a < s`` and ``t < N - s + 1``; the result is indexed
    ``[(a, c), (b, d)]`` (block row major).  It is computed from the ``s`` lagged products
    ``Σ_t z[t]ᵀ z[t + d]`` over the whole record, corrected for the few samples each block row
    does not see, so the cost is ``O(N s m²)`` and the memory ``O(N m)``: the ``(s m) × N``
    matrix ``H`` is never formed.

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
    G = np.empty((s, m, s, m))
    for d in range(s):
        full = z[: N - d].T @ z[d:]  # Σ_{t < N-d} z[t] z[t+d]ᵀ
        # block (a, a+d) sums t over [a, a + j); remove the head t < a and the tail t >= a + j.
        head = np.zeros((m, m))
        tail = z[j : N - d].T @ z[j + d :]
        for a in range(s - d):
            blk = full - head - tail
            G[a, :, a + d, :] = blk
            G[a + d, :, a, :] = blk.T
            head += np.outer(z[a], z[a + d])
            if a + j < N - d:
                tail -= np.outer(z[a + j], z[a + j + d])
    return G.reshape(s * m, s * m)


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


class _DualFilter:
    """Block-recursive simulation of the dual states ``w_pj[k+1] = Aᵀ w_pj[k] + c_p u_j[k]``.

    Within a block of ``BLOCK`` samples the response is one Toeplitz matrix product for all
    outputs ``p`` and inputs ``j`` at once; the state is carried from block to block by one
    ``(Aᵀ)^BLOCK`` product, so the Python loop runs ``N / BLOCK`` times instead of ``N``.
    """

    def __init__(self, A: FloatArray, C: FloatArray, block: int = BLOCK) -> None:
        n, ny = A.shape[0], C.shape[0]
        self.n, self.ny, self.block = n, ny, block
        F = A.T
        powers = np.empty((block + 1, n, n))
        powers[0] = np.eye(n)
        for r in range(1, block + 1):
            powers[r] = F @ powers[r - 1]
        self.powers = powers  # (Aᵀ)^r
        imp = powers[:block] @ C.T  # (Aᵀ)^r Cᵀ: (block, n, ny)
        T = np.zeros((block + 1, n, ny, block))  # T[r, :, :, s] = (Aᵀ)^(r-1-s) Cᵀ for s < r
        for r in range(1, block + 1):
            T[r, :, :, :r] = imp[r - 1 :: -1].transpose(1, 2, 0)
        self.T = T.reshape((block + 1) * n * ny, block)

    def run(self, u: FloatArray, w0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Dual states for ``k < len(u)`` and the state after the last block.

        ``u`` is ``(N, nu)``; ``w0`` is ``(n, ny·nu)``.  Returns ``W`` of shape
        ``(N, ny, nu, n)`` (``W[k, p, j] = w_pj[k]``) and the state after ``ceil(N / BLOCK)``
        blocks, which is the state after ``N`` samples when ``N`` is a multiple of ``BLOCK``.
        """
        N, nu = u.shape
        n, ny, L = self.n, self.ny, self.block
        nb = -(-N // L)
        q = ny * nu
        up = np.zeros((nb * L, nu))
        up[:N] = u
        ub = up.reshape(nb, L, nu).transpose(1, 0, 2).reshape(L, nb * nu)
        forced = (self.T @ ub).reshape(L + 1, n, ny, nb, nu)  # [r, i, p, b, j]
        starts = np.empty((nb + 1, n, q))
        starts[0] = w0
        ends = forced[L].transpose(2, 0, 1, 3).reshape(nb, n, q)
        FL = self.powers[L]
        for b in range(nb):
            starts[b + 1] = FL @ starts[b] + ends[b]
        # free response (Aᵀ)^r starts[b] of every block, as one product
        free = self.powers[:L].reshape(L * n, n) @ starts[:nb].transpose(1, 0, 2).reshape(n, nb * q)
        W = free.reshape(L, n, nb, ny, nu) + forced[:L].transpose(0, 1, 3, 2, 4)
        W = W.transpose(2, 0, 3, 4, 1).reshape(nb * L, ny, nu, n)  # [k, p, j, i]
        return W[:N], starts[nb]

    def free(self, v0: FloatArray, N: int) -> tuple[FloatArray, FloatArray]:
        """Free response ``v[k] = (Aᵀ)ᵏ v0`` for ``k < N`` (shape ``(N,) + v0.shape``) and ``v[N']``.

        ``N'`` is ``N`` rounded up to a multiple of ``BLOCK``.  Once the response has decayed
        below ``1e-50`` of ``v0`` it is set to exactly zero: floating-point subnormals would
        slow every later product down by orders of magnitude.
        """
        n, L = self.n, self.block
        nb = -(-N // L)
        q = v0.shape[1]
        starts = np.zeros((nb + 1, n, q))
        starts[0] = v0
        tiny = 1e-50 * float(np.max(np.abs(v0), initial=0.0))
        for b in range(nb):
            starts[b + 1] = self.powers[L] @ starts[b]
            if not np.max(np.abs(starts[b + 1])) > tiny:  # negligible: stop before subnormals
                starts[b + 1] = 0.0
                break
        V = self.powers[:L].reshape(L * n, n) @ starts[:nb].transpose(1, 0, 2).reshape(n, nb * q)
        V = V.reshape(L, n, nb, q).transpose(2, 0, 1, 3).reshape(nb * L, n, q)
        return V[:N], starts[nb]


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
    The normal equations are accumulated over time chunks (memory independent of the record
    length), equilibrated and solved by a rank-revealing (SVD) least-squares solver.

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
    filt = _DualFilter(A, C)
    for e, (u, y) in enumerate(experiments):
        N = u.shape[0]
        w = np.zeros((n, ny * nu))
        v = C.T.copy()  # (Aᵀ)ᵏ Cᵀ: the x0 regressors, decaying for a stable A
        for k0 in range(0, N, CHUNK):
            uc, yc = u[k0 : k0 + CHUNK], y[k0 : k0 + CHUNK]
            Nc = uc.shape[0]
            W, w = filt.run(uc, w)
            # one regression row per (output p, sample k): columns b_j (j, i), D (p, j), x0
            parts = [W.transpose(1, 0, 2, 3).reshape(ny * Nc, nB)]
            cols = [np.arange(nB)]
            if nD:
                XD = np.zeros((ny, Nc, ny, nu))
                for p in range(ny):
                    XD[p, :, p] = uc
                parts.append(XD.reshape(ny * Nc, nD))
                cols.append(nB + np.arange(nD))
            if nx and np.any(v):
                V, v = filt.free(v, Nc)
                parts.append(V.transpose(2, 0, 1).reshape(ny * Nc, n))
                cols.append(n_shared + nx * e + np.arange(nx))
            Phi = np.hstack(parts) if len(parts) > 1 else parts[0]
            idx = np.concatenate(cols)
            yv = yc.T.reshape(-1)
            M[np.ix_(idx, idx)] += Phi.T @ Phi
            rhs[idx] += Phi.T @ yv
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
