"""A dead time switched on at rest against one started in steady state (benchmarks/README.md,
"A dead time switched on at rest").

A second-order plant, ``y = 1.5 y₋₁ − 0.7 y₋₂ + 0.1 v₋₁ + 0.05 v₋₂`` with ``v`` the input
``d`` samples late (random steps of ±1 held 8 samples, 1 % noise, 2,000 training and 1,000
validation samples at 10 ms): either at rest with zeros before the record (``zero``: how most
generators write a dead time) or in the steady state of its first input (``u0``).  Prints
``diagnose``'s causes and each step's gain at default options::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_dead_time_start.py
"""

from __future__ import annotations

import numpy as np

import tendonkit as tk
from tendonkit.diagnose import diagnose


def plant(n: int, seed: int, d: int, start: str) -> tk.Dataset:
    """One record (``start``: ``"zero"`` at rest, ``"u0"`` in the steady state of ``u[0]``)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 8 + 1), 8)[:n]
    before = np.zeros(d) if start == "zero" else np.full(d, u[0])
    v = np.concatenate([before, u])[:n]
    y = np.zeros(n)
    if start != "zero":
        y[:2] = 0.75 * u[0]  # the steady state: 0.15 / (1 - 1.5 + 0.7)
    for k in range(2, n):
        y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * v[k - 1] + 0.05 * v[k - 2]
    y += 0.01 * rng.standard_normal(n)
    return tk.Dataset.from_arrays(u[:, None], y[:, None], 0.01)


def main() -> None:
    for d in (5, 12, 30):
        for start in ("zero", "u0"):
            for seed in (1, 2):
                train, valid = plant(2000, seed, d, start), plant(1000, seed + 50, d, start)
                dd = diagnose(train, valid, progress=False)
                gains = [round(s.gain, 2) for s in dd.steps]
                print(d, start, seed, dd.causes, gains, flush=True)


if __name__ == "__main__":
    main()
