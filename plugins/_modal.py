"""A linear state-space model in modal coordinates, its simulation and its exact Jacobian.

The prediction-error identifier (:mod:`tendonkit.plugins.pem`) refines models in this form.
Every mode ``m`` is a first-order recursion ``s[k+1] = p s[k] + b·Δu[k]`` (``Δu = u - u0``)
with a real pole, a complex pole (one complex state standing for a conjugate pair, two real
states), or a pole fixed at 1 (an integrator).  The outputs are
``y[k] = Σ_m Re(c_m s_m[k]) + D Δu[k] + y0``.

Why this form:

- **Well-conditioned and small.**  A block-diagonal ``A`` has ``n`` parameters instead of
  ``n²``; the poles are the parameters, so stability is a *bound* (``|p| <= radius``, with
  complex poles as radius and angle) rather than a penalty, and an integrator is a pole that
  is not a parameter at all.
- **Exact derivatives for the price of a few filters.**  Every sensitivity is a first-order
  filter: ``∂s/∂b_j`` is ``Δu_j`` filtered by ``1/(q - p)``, ``∂s/∂p`` is ``s`` itself filtered
  the same way, ``∂s/∂s0 = p^k``.  One Jacobian costs about ``modes·(inputs + 2)`` first-order
  filters (:func:`_first_order`, a compiled loop over the record that gives the numbers
  :func:`scipy.signal.lfilter` gives, in half its time) — far less than the
  ``n² + n(nu + ny)`` simulations of finite differences, and exact.

The parameters' Gauss–Newton covariance (:func:`gauss_newton_covariance`) is mapped to the
entries of the stored matrices by :func:`entry_covariance`, for both of pem's criteria.

The redundancy left (each mode's ``b`` and ``c`` can trade a common scale) is a one-dimensional
valley per mode that the trust-region solver handles; MATLAB's ``ssest`` removes the same kind
of redundancy of its full parameterisation with data-driven local coordinates.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

from tendonkit.schema import StateSpace

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Largest pole modulus of a stable mode (as n4sid's stabilisation).
STABLE_RADIUS = 1.0 - 1e-6


@dataclass(frozen=True)
class Layout:
    """Which modes there are, and where each parameter sits in the vector θ."""

    kinds: tuple[str, ...]  # per mode: "real", "complex" or "integrator"
    nu: int
    ny: int
    n_exp: int
    feedthrough: bool
    output_offset: bool
    input_offset: bool

    @property
    def n_states(self) -> int:
        return sum(2 if k == "complex" else 1 for k in self.kinds)

    def _width(self, kind: str) -> int:
        return 2 if kind == "complex" else 1

    @functools.cached_property
    def slices(self) -> dict[str, list[slice]]:
        """Per group a list of slices into θ (per mode for poles, b, c, s0); computed once."""
        pos = 0
        out: dict[str, list[slice]] = {"pole": [], "b": [], "c": [], "s0": []}

        def take(k: int) -> slice:
            nonlocal pos
            s = slice(pos, pos + k)
            pos += k
            return s

        for kind in self.kinds:
            w = self._width(kind)
            out["pole"].append(take(0 if kind == "integrator" else w))
            out["b"].append(take(w * self.nu))
            out["c"].append(take(w * self.ny))
        out["D"] = [take(self.ny * self.nu if self.feedthrough else 0)]
        out["y0"] = [take(self.ny if self.output_offset else 0)]
        out["u0"] = [take(self.nu if self.input_offset else 0)]
        for _ in range(self.n_exp):
            for kind in self.kinds:
                out["s0"].append(take(self._width(kind)))
        out["end"] = [slice(pos, pos)]
        return out

    @property
    def size(self) -> int:
        return self.slices["end"][0].start


@dataclass
class Modes:
    """The model decoded from θ (complex arrays; real modes have zero imaginary parts)."""

    p: ComplexArray  # (M,)
    b: ComplexArray  # (M, nu)
    c: ComplexArray  # (ny, M)
    D: FloatArray
    y0: FloatArray
    u0: FloatArray
    s0: list[ComplexArray]  # per experiment (M,)


def decode(layout: Layout, theta: FloatArray) -> Modes:
    sl = layout.slices
    M, nu, ny = len(layout.kinds), layout.nu, layout.ny
    p = np.empty(M, complex)
    b = np.empty((M, nu), complex)
    c = np.empty((ny, M), complex)
    for m, kind in enumerate(layout.kinds):
        pv, bv, cv = theta[sl["pole"][m]], theta[sl["b"][m]], theta[sl["c"][m]]
        if kind == "integrator":
            p[m], b[m], c[:, m] = 1.0, bv, cv
        elif kind == "real":
            p[m], b[m], c[:, m] = pv[0], bv, cv
        else:
            p[m] = pv[0] * np.exp(1j * pv[1])
            b[m] = bv[:nu] + 1j * bv[nu:]
            c[:, m] = cv[:ny] + 1j * cv[ny:]
    D = theta[sl["D"][0]].reshape(ny, nu) if layout.feedthrough else np.zeros((ny, nu))
    y0 = theta[sl["y0"][0]] if layout.output_offset else np.zeros(ny)
    u0 = theta[sl["u0"][0]] if layout.input_offset else np.zeros(nu)
    s0 = []
    for e in range(layout.n_exp):
        z = np.empty(M, complex)
        for m, kind in enumerate(layout.kinds):
            v = theta[sl["s0"][e * M + m]]
            z[m] = v[0] + 1j * v[1] if kind == "complex" else v[0]
        s0.append(z)
    return Modes(p, b, c, D, y0, u0, s0)


@njit(cache=True, nogil=True)
def _first_order(b0, b1, a1, x, out, finite):  # pragma: no cover - numba
    """``lfilter([b0, b1], [1, a1], x, axis=0)`` into ``out`` (both ``(N, C)``), operation for
    operation as scipy's direct form II transposed, ``y = z + b0·x``, ``z = b1·x - a1·y``: the
    same numbers, in half the time of scipy's loop (which pays a generic call per sample).
    ``g[k+1] = p g[k] + x[k]`` (``b0 = 0``, ``b1 = 1``) on a ``finite`` ``x`` skips the
    products by 0 and 1, which there change at most the sign of a zero."""
    for c in range(x.shape[1]):
        z = 0.0 * b0  # zero, of the filter's type
        if finite and b0 == 0.0 and b1 == 1.0:
            for k in range(x.shape[0]):
                out[k, c] = z
                z = x[k, c] - a1 * z
            continue
        for k in range(x.shape[0]):
            xk = x[k, c]
            y = z + b0 * xk
            out[k, c] = y
            z = b1 * xk - a1 * y


def _lfilter1(b0: complex, b1: complex, a1: complex, x: NDArray[np.generic]) -> Any:
    """:func:`_first_order` along axis 0 of a 1-D or 2-D ``x``, in the type lfilter gives."""
    dtype = np.result_type(np.asarray(b0), np.asarray(b1), np.asarray(a1), x, np.float64)
    x2 = np.ascontiguousarray(x.reshape(x.shape[0], -1), dtype=dtype)
    out = np.empty_like(x2)
    finite = bool(np.all(np.isfinite(x2)))
    _first_order(dtype.type(b0), dtype.type(b1), dtype.type(a1), x2, out, finite)
    return out.reshape(x.shape)


def _filter(p: complex, x: NDArray[np.generic]) -> ComplexArray:
    """``g[k+1] = p g[k] + x[k]``, ``g[0] = 0`` along axis 0."""
    return np.asarray(_lfilter1(0.0, 1.0, -p, x))


def mode_states(modes: Modes, du: FloatArray, e: int) -> ComplexArray:
    """Mode trajectories ``s`` (N, M) of experiment ``e``."""
    N = du.shape[0]
    k = np.arange(N)
    out = np.empty((N, modes.p.size), complex)
    for m, p in enumerate(modes.p):
        forced = _filter(p, du @ modes.b[m])
        out[:, m] = forced + modes.s0[e][m] * _powers(p, k)
    return out


def _powers(p: complex, k: NDArray[np.int_]) -> ComplexArray:
    """``p**k`` by the recursion itself (a filtered impulse: 30 times faster than ``power``)."""
    impulse = np.zeros(k.size, dtype=complex if isinstance(p, complex) else float)
    impulse[:1] = 1.0
    with np.errstate(under="ignore"):
        return np.asarray(_lfilter1(1.0, 0.0, -p, impulse))


def outputs(modes: Modes, s: ComplexArray, du: FloatArray) -> FloatArray:
    return np.asarray((s @ modes.c.T).real + du @ modes.D.T + modes.y0)


def simulate(layout: Layout, theta: FloatArray, u: FloatArray, e: int) -> FloatArray:
    """Outputs (N, ny) of experiment ``e`` for input ``u``."""
    modes = decode(layout, theta)
    du = u - modes.u0
    return outputs(modes, mode_states(modes, du, e), du)


def jacobian(layout: Layout, theta: FloatArray, u: FloatArray, e: int) -> FloatArray:
    """``∂y/∂θ`` of experiment ``e``, shape (N, ny, size)."""
    modes = decode(layout, theta)
    sl = layout.slices
    nu, ny, M = layout.nu, layout.ny, len(layout.kinds)
    du = u - modes.u0
    N = du.shape[0]
    k = np.arange(N)
    J = np.zeros((N, ny, layout.size))
    s = mode_states(modes, du, e)
    ones = np.ones((N, 1))
    for m, kind in enumerate(layout.kinds):
        p, cm = modes.p[m], modes.c[:, m]
        g = _filter(p, du)  # (N, nu): ∂s/∂b_j
        # ∂y/∂c: Re(c s) -> s for Re(c), -Im... as Re(i c s) = -Im(c s)
        cs = sl["c"][m]
        if kind == "complex":
            J[:, :, cs.start : cs.start + ny] = s[:, m].real[:, None, None] * np.eye(ny)
            J[:, :, cs.start + ny : cs.stop] = -s[:, m].imag[:, None, None] * np.eye(ny)
        else:
            J[:, :, cs] = s[:, m].real[:, None, None] * np.eye(ny)
        bs = sl["b"][m]
        cg = g[:, None, :] * cm[None, :, None]  # (N, ny, nu)
        J[:, :, bs.start : bs.start + nu] = cg.real
        if kind == "complex":
            J[:, :, bs.start + nu : bs.stop] = -cg.imag  # Re(i c g)
        if kind != "integrator":
            h = _filter(p, s[:, m])  # ∂s/∂p
            ps = sl["pole"][m]
            ch = h[:, None] * cm[None, :]
            if kind == "real":
                J[:, :, ps.start] = ch.real
            else:
                phi = theta[ps.start + 1]
                J[:, :, ps.start] = (ch * np.exp(1j * phi)).real
                J[:, :, ps.start + 1] = (ch * 1j * p).real
        if layout.input_offset:  # Δu = u - u0: ∂y/∂u0 = -(c g1 b + D)
            g1 = _filter(p, ones)[:, 0]
            J[:, :, sl["u0"][0]] -= (g1[:, None, None] * cm[None, :, None] * modes.b[m]).real
        zs = sl["s0"][e * M + m]
        pk = _powers(p, k)[:, None] * cm[None, :]
        J[:, :, zs.start] = pk.real
        if kind == "complex":
            J[:, :, zs.start + 1] = -pk.imag
    if layout.feedthrough:
        ds = sl["D"][0]
        for i in range(ny):
            J[:, i, ds.start + i * nu : ds.start + (i + 1) * nu] = du
    if layout.output_offset:
        J[:, :, sl["y0"][0]] = np.eye(ny)
    if layout.input_offset:
        J[:, :, sl["u0"][0]] -= modes.D[None, :, :]
    return J


def from_state_space(
    A: FloatArray,
    B: FloatArray,
    C: FloatArray,
    D: FloatArray,
    x0s: list[FloatArray],
    *,
    integrators: int,
    feedthrough: bool,
    output_offset: bool,
    input_offset: bool,
    y0: FloatArray,
    u0: FloatArray,
    radius: float,
) -> tuple[Layout, FloatArray]:
    """θ of a state-space model; the last ``integrators`` states are pure integrators.

    With integrators the model must have the form ``A = [[A1, 0], [C1, I]]`` (velocity states
    then positions): the positions are shifted so that the integrator modes decouple.
    """
    n, nu = B.shape
    ny = C.shape[0]
    n1 = n - integrators
    A1 = A[:n1, :n1]
    lam, V = np.linalg.eig(A1) if n1 else (np.zeros(0, complex), np.zeros((0, 0), complex))
    Vi = np.linalg.inv(V) if n1 else V
    # integrator modes: q~ = q + C1 (I - A1)^-1 x decouples (see the module notes)
    if integrators:
        C1 = A[n1:, :n1]
        W = C1 @ np.linalg.inv(np.eye(n1) - A1) if n1 else np.zeros((integrators, 0))
        b_int = B[n1:] + W @ B[:n1]
        c_int = C[:, n1:]
        C_modes = (C[:, :n1] - c_int @ W) @ V if n1 else np.zeros((ny, 0))
    else:
        C_modes = C @ V
    b_modes = Vi @ B[:n1]
    kinds: list[str] = []
    parts: list[list[float]] = []
    keep: list[int] = []
    for m, p in enumerate(lam):
        if abs(p.imag) <= 1e-12 * max(1.0, abs(p)):
            kinds.append("real")
            pr = float(np.clip(p.real, -radius, radius))
            parts.append([pr, *b_modes[m].real, *C_modes[:, m].real])
            keep.append(m)
        elif p.imag > 0:
            kinds.append("complex")
            r = float(min(abs(p), radius))
            cm = 2.0 * C_modes[:, m]
            parts.append(
                [r, float(np.angle(p)), *b_modes[m].real, *b_modes[m].imag, *cm.real, *cm.imag]
            )
            keep.append(m)
    for i in range(integrators):
        kinds.append("integrator")
        parts.append([*b_int[i], *c_int[:, i]])
    layout = Layout(tuple(kinds), nu, ny, len(x0s), feedthrough, output_offset, input_offset)
    theta = [v for part in parts for v in part]
    if feedthrough:
        theta += list(D.ravel())
    if output_offset:
        theta += list(y0)
    if input_offset:
        theta += list(u0)
    for x0 in x0s:
        z = Vi @ x0[:n1] if n1 else np.zeros(0)
        if integrators:
            zq = x0[n1:] + W @ x0[:n1]
        for j, m in enumerate(keep):
            if kinds[j] == "complex":
                theta += [z[m].real, z[m].imag]
            else:
                theta.append(z[m].real)
        if integrators:
            theta += list(zq)
    return layout, np.asarray(theta, dtype=float)


def to_state_space(
    layout: Layout, theta: FloatArray
) -> tuple[
    FloatArray, FloatArray, FloatArray, FloatArray, list[FloatArray], FloatArray, FloatArray
]:
    """Real block-diagonal ``A, B, C, D``, initial states per experiment, ``u0``, ``y0``."""
    modes = decode(layout, theta)
    n, nu, ny = layout.n_states, layout.nu, layout.ny
    A, B, C = np.zeros((n, n)), np.zeros((n, nu)), np.zeros((ny, n))
    x0s = [np.zeros(n) for _ in range(layout.n_exp)]
    i = 0
    for m, kind in enumerate(layout.kinds):
        p, b, c = modes.p[m], modes.b[m], modes.c[:, m]
        if kind == "complex":
            A[i : i + 2, i : i + 2] = [[p.real, -p.imag], [p.imag, p.real]]
            B[i], B[i + 1] = b.real, b.imag
            C[:, i], C[:, i + 1] = c.real, -c.imag
            for e in range(layout.n_exp):
                x0s[e][i], x0s[e][i + 1] = modes.s0[e][m].real, modes.s0[e][m].imag
            i += 2
        else:
            A[i, i], B[i], C[:, i] = p.real, b.real, c.real
            for e in range(layout.n_exp):
                x0s[e][i] = modes.s0[e][m].real
            i += 1
    return A, B, C, modes.D.copy(), x0s, modes.u0.copy(), modes.y0.copy()


def bounds(layout: Layout, radius: float) -> tuple[FloatArray, FloatArray]:
    """Box bounds of θ: poles inside ``radius`` (complex: radius in [0, radius], angle in [0, π])."""
    lo = np.full(layout.size, -np.inf)
    hi = np.full(layout.size, np.inf)
    sl = layout.slices
    for m, kind in enumerate(layout.kinds):
        s = sl["pole"][m]
        if kind == "real":
            lo[s], hi[s] = -radius, radius
        elif kind == "complex":
            lo[s.start], hi[s.start] = 0.0, radius
            lo[s.start + 1], hi[s.start + 1] = 0.0, np.pi
    return lo, hi


# -- refinement -------------------------------------------------------------------------------


def residuals(
    layout: Layout,
    theta: FloatArray,
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
) -> FloatArray:
    parts = [((y - simulate(layout, theta, u, k)) / sy).ravel() for k, (u, y) in enumerate(exps)]
    return np.concatenate(parts)


def residual_jacobian(
    layout: Layout,
    theta: FloatArray,
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
) -> FloatArray:
    parts = [
        (-jacobian(layout, theta, u, k) / sy[None, :, None]).reshape(-1, layout.size)
        for k, (u, _) in enumerate(exps)
    ]
    return np.vstack(parts)


def refine(
    layout: Layout,
    theta: FloatArray,
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
    max_nfev: int,
    tol: float = 1e-10,
    radius: float = STABLE_RADIUS,
) -> tuple[FloatArray, float, float, int]:
    """Trust-region least squares on the output-normalised simulation errors of ``exps``.

    Returns ``(theta, rms before, rms after, evaluations)``; ``theta`` is the start when the
    refinement does not lower the error.  Poles stay within ``radius``.
    """
    lo, hi = bounds(layout, radius)
    theta = np.clip(theta, lo, hi)
    r0 = residuals(layout, theta, exps, sy)
    sol = trust_region(
        lambda th: residuals(layout, th, exps, sy),
        theta,
        lambda th: residual_jacobian(layout, th, exps, sy),
        (lo, hi),
        max_nfev,
        tol,
    )
    before, after = rms(r0), rms(sol.fun)
    if not np.isfinite(after) or after > before:
        return theta, before, before, int(sol.nfev)
    return np.asarray(sol.x), before, after, int(sol.nfev)


def rms(r: FloatArray) -> float:
    """Root mean square of the residuals ``r``."""
    return float(np.sqrt(r @ r / r.size))


def trust_region(
    fun: Any, x0: FloatArray, jac: Any, bounds: tuple[FloatArray, FloatArray], max_nfev: int,
    tol: float,
) -> Any:  # fmt: skip
    """scipy's trust-region-reflective least squares as pem's refinements run it: scaled by
    the Jacobian, one tolerance for cost, step and gradient, floating-point warnings off (a
    step outside the domain returns large residuals, not an error)."""
    # lazy: heavy (scipy.optimize)
    from scipy.optimize import least_squares

    with np.errstate(all="ignore"):
        return least_squares(
            fun, x0, jac=jac, bounds=bounds, method="trf", x_scale="jac", max_nfev=max_nfev,
            ftol=tol, xtol=tol, gtol=tol,
        )  # fmt: skip


# -- parameter covariance ---------------------------------------------------------------------


def gauss_newton_covariance(J: FloatArray, r: FloatArray) -> tuple[FloatArray, float] | None:
    """``(λ (JᵀJ)⁺, λ)`` of a least-squares fit with Jacobian ``J`` and residuals ``r`` at the
    optimum, ``λ`` the residuals' variance; None when ``J`` has rank 0 or no residual is left
    over."""
    s = np.linalg.svd(J, compute_uv=False)
    rank = int(np.sum(s > 1e-10 * s[0])) if s.size and s[0] > 0 else 0
    if rank == 0 or r.size <= rank:
        return None
    lam = float(r @ r) / (r.size - rank)
    cov = np.asarray(lam * np.linalg.pinv(J.T @ J, rcond=1e-10, hermitian=True), dtype=float)
    return cov, lam


def entry_covariance(
    layout: Layout, z: FloatArray, cov_z: FloatArray, lam: float, rep: StateSpace
) -> dict[str, Any]:
    """The covariance ``cov_z`` of ``z`` — θ, then the entries of a Kalman gain ``K`` (n, ny)
    row by row where ``z`` is longer than θ — mapped to the entries of the stored state space
    ``rep`` that vary (``"A[0,1]"``, … :mod:`tendonkit.uncertainty`'s names); the initial
    states are left out.  The map from θ to the stored matrices involves no simulation and is
    differentiated numerically."""
    s0 = {i for part in layout.slices["s0"] for i in range(part.start, part.stop)}
    free = [i for i in range(z.size) if i not in s0]
    keys: list[tuple[str, Any]] = [("A", rep.A), ("B", rep.B), ("C", rep.C), ("D", rep.D)]
    if z.size > layout.size:
        keys.append(("K", z[layout.size :].reshape(layout.n_states, layout.ny)))
    if rep.u0 is not None:
        keys.append(("u0", rep.u0))
    if rep.y0 is not None:
        keys.append(("y0", rep.y0))
    names = [
        f"{k}[{','.join(str(i) for i in idx)}]"
        for k, arr in keys
        for idx in np.ndindex(np.shape(arr))
    ]

    def flat(v: FloatArray) -> FloatArray:
        A, B, C, D, _, u0, y0 = to_state_space(layout, v[: layout.size])
        parts = {"A": A, "B": B, "C": C, "D": D, "K": v[layout.size :], "u0": u0, "y0": y0}
        return np.concatenate([np.ravel(parts[k]) for k, _ in keys])

    T = np.empty((len(names), len(free)))
    for c, i in enumerate(free):
        h = 1e-7 * max(abs(z[i]), 1e-3)
        up, down = z.copy(), z.copy()
        up[i] += h
        down[i] -= h
        T[:, c] = (flat(up) - flat(down)) / (2 * h)
    keep = np.flatnonzero(np.any(np.abs(T) > 1e-12, axis=1))
    Tk = T[keep]
    cov = Tk @ cov_z[np.ix_(free, free)] @ Tk.T
    return {
        "parameters": [names[i] for i in keep],
        "matrix": cov.tolist(),
        "noise_variance": lam,
    }
