"""Linear responses and delay taps shared by the simulators and the realisations.

A private module below :mod:`tendonkit.simulate` (which re-exports its public names):
:mod:`tendonkit._simulate_arx` and :mod:`tendonkit.realize` use it without importing the
simulator, so the core's imports form no cycle.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from ._kernel import state_loop

FloatArray = NDArray[np.float64]
#: The initial state of a free run: zero, the model's ``x0``, estimated, or given.
Initial = Literal["zero", "model", "estimate"] | FloatArray


def split_delay(samples: float) -> tuple[int, float]:
    """Whole samples ``n`` and fraction ``α`` of a delay (``α`` rounded to 1e-12 to 0 or 1)."""
    n = math.floor(samples + 1e-12)
    a = samples - n
    return n, (0.0 if a < 1e-12 else a)


def fractional_delay(s: FloatArray, samples: float, before: float | None = None) -> FloatArray:
    """``v[k] = (1-α) s[k-n] + α s[k-n-1]`` (``n``, ``α`` from :func:`split_delay`).

    The signal before the first sample is ``before`` (default ``s[0]``).  A fractional delay
    of a zero-order-held signal, averaged over the frame, is exactly this two-tap filter.
    """
    n, a = split_delay(samples)
    if n == 0 and a == 0:
        return s.copy()
    N = len(s)
    pad = np.concatenate([np.full(n + 1, s[0] if before is None else before), s])
    out = pad[1 : N + 1].copy()
    if a:
        out = (1.0 - a) * out + a * pad[:N]
    return out


def delay_taps(samples: float) -> FloatArray:
    """FIR taps of a delay block: ``v[k] = Σ_i taps[i] s[k-i]``."""
    n, a = split_delay(samples)
    taps = np.zeros(n + (2 if a else 1))
    taps[n] = 1.0 - a
    if a:
        taps[n + 1] = a
    return taps


def ss_response(
    A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray, u: FloatArray, x0: FloatArray
) -> FloatArray:
    """Outputs of ``x+ = Ax + Bu, y = Cx + Du`` from ``x0``.

    Long records are simulated in blocks of ``L`` samples: inside a block the output is an
    observability product on the block's start state plus a block-Toeplitz product on its
    inputs, and only the start states are propagated in a Python loop (``N / L`` iterations).
    The result equals the sample-by-sample recursion to rounding error.
    """
    n, N = A.shape[0], u.shape[0]
    if N < 512 or n == 0:
        return _ss_loop(A, B, C, D, u, x0)
    L = 32 if n > 24 else 64
    ny, nu = C.shape[0], B.shape[1]
    # Ob[r] = C A^r (r < L), H[r] = C A^(r-1) B (r >= 1), G[r] = A^(L-1-r) B, AL = A^L
    Ob = np.empty((L, ny, n))
    P = np.eye(n)
    for r in range(L):
        Ob[r] = C @ P
        P = A @ P
    AL = P
    H = np.zeros((L, ny, nu))
    Gs = np.empty((L, n, nu))
    for r in range(1, L):
        H[r] = Ob[r - 1] @ B
    powB = B.copy()
    for r in range(L - 1, -1, -1):
        Gs[r] = powB
        powB = A @ powB
    nb = -(-N // L)
    up = np.zeros((nb * L, nu))
    up[:N] = u
    Ub = up.reshape(nb, L, nu)  # [b, s, j]
    # forced outputs: Y[b, r] = sum_{s<r} H[r-s] u[b, s]
    T = np.zeros((L, ny, L, nu))
    for r in range(1, L):
        T[r, :, :r, :] = H[r:0:-1].transpose(1, 0, 2)
    forced = (T.reshape(L * ny, L * nu) @ Ub.reshape(nb, L * nu).T).T.reshape(nb, L, ny)
    ctrl = Gs.transpose(1, 0, 2).reshape(n, L * nu)
    xin = (ctrl @ Ub.reshape(nb, L * nu).T).T  # (nb, n): state added by each block's inputs
    # the block-start states, x_{b+1} = A^L x_b + xin_b: a short recursion, compiled
    starts = state_loop(np.ascontiguousarray(AL), np.ascontiguousarray(xin), _vector(x0))
    free = (starts @ Ob.reshape(L * ny, n).T).reshape(nb, L, ny)
    Y = (free + forced).reshape(nb * L, ny)[:N]
    return Y + u @ D.T


def _vector(x0: FloatArray) -> FloatArray:
    return np.ascontiguousarray(np.asarray(x0, dtype=float).reshape(-1))


def _ss_loop(
    A: FloatArray, B: FloatArray, C: FloatArray, D: FloatArray, u: FloatArray, x0: FloatArray
) -> FloatArray:
    """Sample-by-sample recursion (short records and reference for tests)."""
    n, N = A.shape[0], u.shape[0]
    X = np.empty((N, n))
    x = np.asarray(x0, dtype=float).copy()
    Bu = u @ B.T
    At = A.T
    for k in range(N):
        X[k] = x
        x = x @ At + Bu[k]
    return X @ C.T + u @ D.T
