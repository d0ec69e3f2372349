"""The tall QR under every least-squares fit: tendonkit's ``r_factor`` against SciPy's ``qr``.

Run from the repository root, one BLAS thread (benchmarks/README.md gives the results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_lstsq.py

``tendonkit.regression.r_factor`` gives the triangular factor of the stacked regressors and
targets of an ARX (and of diagnose's extensions, SINDYc's library and the simulation-error
refinement's Jacobian).  It calls LAPACK's Householder ``geqrf`` on blocks of rows (TSQR).  The
peer is the same blocked scheme on ``scipy.linalg.qr(mode="r")`` (what ``r_factor`` used before
2026-11-26).  Both give the same ``R`` up to the signs of its rows; the script checks that, then
times each shape (median of repeats of at least 0.3 s) and prints the ratio.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np
from scipy.linalg import qr

from tendonkit.regression import QR_BLOCK, r_factor

#: (rows, columns): ARX(8, 8) regressions of the robot (4 inputs, 2 outputs: 48 + 2 targets)
#: on 2, 4 and 30 minutes at 30 ms; a SISO ARX(8, 8) on Silverbox's 65,000 training samples;
#: a refinement Jacobian of 30 parameters on 10^5 residuals.
SHAPES = ((3000, 20), (8000, 50), (30000, 50), (65000, 18), (100000, 31))


def scipy_r(A: np.ndarray, block: int = 4096) -> np.ndarray:
    """The blocked scheme on ``scipy.linalg.qr(mode="r")`` (the peer)."""
    n, c = A.shape
    block = max(block, 4 * c)
    if n <= 2 * block:
        return np.asarray(qr(A, mode="r", check_finite=False)[0][:c])
    parts = [qr(A[i : i + block], mode="r", check_finite=False)[0][:c] for i in range(0, n, block)]
    return np.asarray(qr(np.vstack(parts), mode="r", check_finite=False)[0][:c])


def timed(f: Callable[..., object], *args: object) -> float:
    f(*args)
    times: list[float] = []
    start = time.perf_counter()
    while time.perf_counter() - start < 0.3 or len(times) < 5:
        t = time.perf_counter()
        f(*args)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    print(f"load average before: {os.getloadavg()[0]:.2f}; QR_BLOCK {QR_BLOCK}")
    print(f"{'rows':>7} {'cols':>4} {'scipy qr (ms)':>14} {'r_factor (ms)':>14} {'ratio':>6}")
    for n, c in SHAPES:
        A = np.random.default_rng(0).standard_normal((n, c))
        ours, peer = r_factor(A), scipy_r(A)
        err = np.max(np.abs(np.abs(ours) - np.abs(peer))) / np.max(np.abs(peer))
        assert err < 1e-12, f"factors differ by {err:.1e}"
        t_peer, t_ours = timed(scipy_r, A), timed(r_factor, A)
        print(f"{n:7d} {c:4d} {1e3 * t_peer:14.2f} {1e3 * t_ours:14.2f} {t_peer / t_ours:6.2f}")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
