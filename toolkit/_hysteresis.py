"""Hysteresis operators run along a whole record, compiled (numba).

:func:`tendonkit.terms._run_stateful` is the reference: the same recursions in Python, one
sample at a time.  These loops serve the whole-record evaluations (regression, one-step
prediction), where a candidate extension of a long record would otherwise cost a Python loop
per sample.  The per-step evaluation inside simulations is in :mod:`tendonkit._kernel`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def play_record(z, width):  # pragma: no cover - numba
    """Values and derivatives of a play of half-width ``width`` along ``z``, from ``p = z[0]``."""
    n = z.shape[0]
    val = np.empty(n)
    der = np.empty(n)
    p = 0.0
    for k in range(n):
        if k == 0:
            q = z[0]
            d = 1.0
        else:
            q = min(max(p, z[k] - width), z[k] + width)
            d = 1.0 if q != p else 0.0
        p = q
        val[k] = q
        der[k] = d
    return val, der


@njit(cache=True, nogil=True)
def bouc_wen_record(z, a, b):  # pragma: no cover - numba
    """Values and derivatives of the Bouc-Wen operator ``(a, b)`` along ``z``, from ``h = 0``."""
    n = z.shape[0]
    val = np.empty(n)
    der = np.empty(n)
    h = 0.0
    for k in range(n):
        if k == 0:
            val[0] = 0.0
            der[0] = 1.0
            continue
        d = z[k] - z[k - 1]
        s = 1.0 if d > 0 else (-1.0 if d < 0 else 0.0)
        der[k] = 1.0 - a * s * h - b * abs(h)
        h = h + d - a * abs(d) * h - b * d * abs(h)
        val[k] = h
    return val, der
