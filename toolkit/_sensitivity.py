"""Forward sensitivities of an ARX simulation (compiled): the exact simulation-error Jacobian.

``output_error.refine`` minimises the free-run simulation error of a model.  Its Jacobian by
forward differences costs one simulation per parameter per iteration — for an ARX with four
inputs, eight lags and a few dozen terms, over two hundred simulations each step.  For an ARX
(with memoryless terms) the derivative of the simulated output with respect to every
coefficient obeys the model's own recursion, linearised along the simulation:

    S[k] = Φ[k] - Σ_w A_w S[k-w] + Σ_t c_t Σ_q ∂θ_t/∂ŷ_q[k] S[k - lag_q]

where ``Φ[k]`` is the regressor of each coefficient evaluated on the simulated outputs (the
direct derivative) and the last sum runs over the terms' readings of past outputs.  One pass
over the record gives every column at the cost of a few simulations.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def arx_sensitivity(Phi, A, coef, J, qcol, qlag, start, L):  # pragma: no cover - numba
    """``S`` (N + L, ny, P): sensitivities of the simulated outputs from sample ``start``.

    ``Phi`` (N, ny, P) the direct derivatives; ``A`` (na, ny, ny); ``coef`` (nt, ny) the term
    coefficients; ``J`` (nt, nq, N) the terms' derivatives with respect to their ``nq``
    readings of past outputs, output ``qcol[q]`` at lag ``qlag[q]``.  Rows before ``L + start``
    are zero (measured history).
    """
    N, ny, P = Phi.shape
    na = A.shape[0]
    nt = coef.shape[0]
    nq = qcol.shape[0]
    S = np.zeros((N + L, ny, P))
    for k in range(start, N):
        kk = k + L
        for i in range(ny):
            row = S[kk, i]
            for p in range(P):
                row[p] = Phi[k, i, p]
            for w in range(na):
                past = S[kk - 1 - w]
                for j in range(ny):
                    a = A[w, i, j]
                    if a != 0.0:
                        for p in range(P):
                            row[p] -= a * past[j, p]
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
