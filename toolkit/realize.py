"""Exact state-space realisations of the linear representations (for MPC, FMUs, python-control)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ._representations import ARX, StateSpace, section_gain
from ._response import delay_taps
from .errors import SchemaError

if TYPE_CHECKING:
    from .schema import Model


def arx_lag_matrices(rep: ARX, nu: int) -> list[np.ndarray]:
    """Input coefficients per lag ``G_l`` so that ``y[k] += sum_l G_l u[k-l]`` (delays folded in)."""
    ny = rep.A[0].shape[0] if rep.A else rep.B[0].shape[0]
    nk = list(rep.nk)
    length = (max(nk) if nk else 0) + rep.nb
    G = [np.zeros((ny, nu)) for _ in range(max(length, 1))]
    for j, Bj in enumerate(rep.B):
        for m in range(nu):
            G[j + nk[m]][:, m] = Bj[:, m]
    return G


def arx_to_state_space(rep: ARX, nu: int) -> StateSpace:
    """Shift-register realisation of an ARX model (non-minimal, exact).

    The state is ``[y[k-1], ..., y[k-na], u[k-1], ..., u[k-L]]``; ``y[k] = C x[k] + D u[k]``.
    An ``offset`` or nonlinear ``terms`` cannot be realised and raise :class:`SchemaError`.
    """
    if rep.terms:
        raise SchemaError("An ARX model with nonlinear terms has no linear state-space form.")
    if rep.offset is not None and np.any(rep.offset != 0):
        raise SchemaError("An ARX model with a non-zero offset is affine, not linear.")
    G = arx_lag_matrices(rep, nu)
    ny = G[0].shape[0]
    na, L = rep.na, len(G) - 1
    n = ny * na + nu * L
    C = np.zeros((ny, n))
    for i, Ai in enumerate(rep.A):
        C[:, i * ny : (i + 1) * ny] = -Ai
    for lag in range(1, L + 1):
        C[:, ny * na + (lag - 1) * nu : ny * na + lag * nu] = G[lag]
    D = G[0].copy()
    A = np.zeros((n, n))
    B = np.zeros((n, nu))
    if na:
        A[:ny, :] = C  # new y[k] becomes the first output block
        B[:ny, :] = D
        A[ny : ny * na, : ny * (na - 1)] = np.eye(ny * (na - 1))
    if L:
        off = ny * na
        B[off : off + nu, :] = np.eye(nu)
        A[off + nu : off + nu * L, off : off + nu * (L - 1)] = np.eye(nu * (L - 1))
    return StateSpace(A=A, B=B, C=C, D=D)


def add_input_delays(ss: StateSpace, delays: Sequence[Any]) -> StateSpace:
    """Prepend input delays as shift-register states.

    ``delays[m]`` is input m's delay in samples (fractional allowed, see
    :func:`tendonkit.simulate.fractional_delay`) or its FIR taps ``v[k] = Σ_i taps[i] u[k-i]``.
    """
    taps = [
        np.atleast_1d(np.asarray(d, dtype=float)) if np.ndim(d) else delay_taps(float(d))  # type: ignore[arg-type]
        for d in delays
    ]
    nu = ss.B.shape[1]
    lengths = [len(t) - 1 for t in taps]  # registers per input
    total = sum(lengths)
    if total == 0 and all(t[0] == 1.0 for t in taps):
        return ss
    n = ss.A.shape[0]
    # delay states: for input m a chain of lengths[m] registers holding u[k-1], ..., u[k-L].
    Ad = np.zeros((total, total))
    Bd = np.zeros((total, nu))
    Cd = np.zeros((nu, total))  # delayed input as a function of the delay states
    Dd = np.zeros((nu, nu))
    pos = 0
    for m, (t, d) in enumerate(zip(taps, lengths, strict=True)):
        Dd[m, m] = t[0]
        if d == 0:
            continue
        Bd[pos, m] = 1.0
        for r in range(1, d):
            Ad[pos + r, pos + r - 1] = 1.0
        Cd[m, pos : pos + d] = t[1:]
        pos += d
    A = np.block([[ss.A, ss.B @ Cd], [np.zeros((total, n)), Ad]])
    B = np.vstack([ss.B @ Dd, Bd])
    C = np.hstack([ss.C, ss.D @ Cd])
    D = ss.D @ Dd
    x0 = None if ss.x0 is None else np.concatenate([ss.x0, np.zeros(total)])
    # the registers hold u - u0 (the taps sum to one, so the delayed deviation is exact)
    return StateSpace(A=A, B=B, C=C, D=D, x0=x0, u0=ss.u0, y0=ss.y0)


def fold_offsets(ss: StateSpace) -> StateSpace:
    """The same model without an operating point: ``u0`` and ``y0`` carried by a constant state.

    ``x[k+1] = A x + B (u - u0)``, ``y = C x + D (u - u0) + y0`` becomes the model with one
    more state ``c`` (``c[k+1] = c``, starting at 1) that adds ``-B u0`` to the state update
    and ``y0 - D u0`` to the outputs.  From the stored initial state (``x0``, and ``c = 1``) the
    two give the same outputs to rounding; they differ only where states are *estimated*
    (which would treat ``c`` as free), which is why simulation keeps the offsets apart.
    A model without offsets is returned unchanged.
    """
    if not ss.has_offsets:
        return ss
    n, nu = ss.B.shape
    ny = ss.C.shape[0]
    u0, y0 = ss.operating_point
    A = np.block([[ss.A, -(ss.B @ u0)[:, None]], [np.zeros((1, n)), np.ones((1, 1))]])
    B = np.vstack([ss.B, np.zeros((1, nu))])
    C = np.hstack([ss.C, (y0 - ss.D @ u0)[:, None]])
    x0 = np.concatenate([np.zeros(n) if ss.x0 is None else ss.x0, [1.0]])
    K = None if ss.K is None else np.vstack([ss.K, np.zeros((1, ny))])
    E = None if ss.E is None else np.vstack([ss.E, np.zeros((1, ss.E.shape[1]))])
    return StateSpace(A=A, B=B, C=C, D=ss.D, x0=x0, K=K, terms=ss.terms, E=E)


def add_input_lag(ss: StateSpace, m: int, pole: float) -> StateSpace:
    """Prepend a first-order lag on input ``m`` as one state.

    The lag block of :func:`tendonkit.simulate.simulate` is ``v[k] = a v[k-1] + (1 - a) u[k-1]``
    (unit static gain, one sample of transport): its state ``w[k] = v[k]`` follows
    ``w⁺ = a w + (1 - a) u`` and feeds the model in place of ``u``.  Like the delay registers,
    the state holds ``u - u0`` (the static gain is one, so the lagged deviation is exact).
    """
    n, nu = ss.B.shape
    a = float(pole)
    A = np.zeros((n + 1, n + 1))
    A[:n, :n] = ss.A
    A[:n, n] = ss.B[:, m]
    A[n, n] = a
    B = np.vstack([ss.B, np.zeros((1, nu))])
    B[:n, m] = 0.0
    B[n, m] = 1.0 - a
    C = np.hstack([ss.C, ss.D[:, m : m + 1]])
    D = ss.D.copy()
    D[:, m] = 0.0
    x0 = None if ss.x0 is None else np.concatenate([ss.x0, np.zeros(1)])
    return StateSpace(A=A, B=B, C=C, D=D, x0=x0, u0=ss.u0, y0=ss.y0)


def add_input_section(ss: StateSpace, m: int, params: dict[str, float]) -> StateSpace:
    """Prepend a ``second_order_section`` on input ``m`` as two states.

    The section ``(1 + b1 q⁻¹ + b2 q⁻²) / (1 + a1 q⁻¹ + a2 q⁻²)`` in controllable form:
    ``w⁺ = [[-a1, -a2], [1, 0]] w + [1, 0]ᵀ d``, ``v = [b1 - a1, b2 - a2] w + d`` (direct
    term 1).  It acts on deviations: with static gain ``g`` the model's operating point
    ``u0`` of the filtered input is ``g`` times the new one of the raw input (a section that
    blocks constants, ``g = 0``, has no raw operating point to give a non-zero one: an error).
    """
    b1, b2, a1, a2 = (float(params[k]) for k in ("b1", "b2", "a1", "a2"))
    n, nu = ss.B.shape
    Af = np.array([[-a1, -a2], [1.0, 0.0]])
    Cf = np.array([b1 - a1, b2 - a2])
    A = np.zeros((n + 2, n + 2))
    A[:n, :n] = ss.A
    A[:n, n:] = np.outer(ss.B[:, m], Cf)
    A[n:, n:] = Af
    B = np.vstack([ss.B, np.zeros((2, nu))])
    B[n, m] = 1.0
    C = np.hstack([ss.C, np.outer(ss.D[:, m], Cf)])
    x0 = None if ss.x0 is None else np.concatenate([ss.x0, np.zeros(2)])
    u0 = ss.u0
    if u0 is not None and u0[m] != 0.0:
        gain = section_gain(params)
        if not abs(gain) > 1e-9:
            raise SchemaError(
                f"A second_order_section on input {m} blocks constant signals (static gain "
                f"{gain:.3g}), so no input gives the model's operating point {u0[m]:.6g} behind it."
            )
        u0 = np.array(u0, dtype=float)
        u0[m] = u0[m] / gain
    K = None if ss.K is None else np.vstack([ss.K, np.zeros((2, ss.K.shape[1]))])
    return StateSpace(A=A, B=B, C=C, D=ss.D.copy(), x0=x0, K=K, u0=u0, y0=ss.y0)


def to_state_space(model: Model) -> StateSpace:
    """Linear state-space form of a linear model, input delay, first-order lag and
    second-order section blocks included (each block is linear and acts on one input, so
    their order does not matter).

    Raises
    ------
    SchemaError
        If the model is nonlinear (``sparse_map``, nonlinear terms or other blocks).
    """
    if not model.is_linear:
        raise SchemaError(f"Model {model.name!r} is nonlinear and has no state-space form.")
    rep = model.representation
    nu = len(model.inputs)
    if isinstance(rep, StateSpace):
        ss = rep
    elif isinstance(rep, ARX):
        ss = arx_to_state_space(rep, nu)
    else:  # pragma: no cover - is_linear excludes it
        raise SchemaError(f"{rep.kind} has no state-space form.")
    taps = [np.ones(1) for _ in range(nu)]
    for b in model.input_blocks:
        if b.kind == "delay":
            m = model.input_names.index(b.signal)
            taps[m] = np.convolve(taps[m], delay_taps(float(b.params["samples"])))
    ss = add_input_delays(ss, taps)
    for b in model.input_blocks:
        if b.kind == "first_order_lag":
            ss = add_input_lag(ss, model.input_names.index(b.signal), float(b.params["pole"]))
        elif b.kind == "second_order_section":
            ss = add_input_section(ss, model.input_names.index(b.signal), dict(b.params))
    return ss
