"""Output-error ARX (``arx`` with ``criterion="simulation"``) against SIPPY's OE, and least squares.

The system: a lightly damped 1 Hz oscillator sampled at 100 Hz, driven by band-limited noise,
with 5 % white noise on the measured output (an output-error system, ``y = B/A u + e``;
``tendonkit.testsystems.lightly_damped_oscillator``).  Every method estimates a second-order
model (two poles, two numerator coefficients, one sample of delay) from ``N`` samples; the
models are scored by their free-run fit on a fresh 20,000-sample record (simulated from rest
with ``scipy.signal.lfilter``, the first 20 s left out) and by the largest distance of their
poles from the true ones.  Times are wall-clock seconds of the estimation call, median of three.

Run from the repository root, in the project's environment with the benchmark requirements::

    python benchmarks/bench_output_error.py            # N = 2000, 6000, 20000
    python benchmarks/bench_output_error.py --sizes 2000
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

METHODS = {
    "tendonkit-ls": "tendonkit arx, least squares (criterion='equation')",
    "tendonkit-oe": "tendonkit arx, output error (criterion='simulation')",
    "sippy-oe": "SIPPY OE (OE_mod='OPT', OE_orders [2, 2, 0])",
}


def _estimate(method: str, train: Any) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator in powers of q^-1: ``b[i]`` at lag ``i``, ``a[0] = 1``."""
    import tendonkit as tk

    if method.startswith("tendonkit"):
        crit = "simulation" if method.endswith("oe") else "equation"
        rep = tk.identify(train, "arx", na=2, nb=2, nk=1, criterion=crit).representation
        b = np.zeros(len(rep.B) + 1)
        b[1:] = [float(x[0, 0]) for x in rep.B]
        return b, np.array([1.0, *[float(a[0, 0]) for a in rep.A]])
    from sippy_unipi import system_identification

    # SIPPY's OE_orders are [nb, nf, delay]; delay 0 gives lags 1 and 2, as nk = 1 above
    g = system_identification(train.y[:, 0], train.u[:, 0], "OE", OE_orders=[2, 2, 0]).G
    num = np.trim_zeros(np.asarray(g.num[0][0], dtype=float), "f")
    den = np.asarray(g.den[0][0], dtype=float)
    shift = len(den) - len(num)  # num(z)/den(z): the first numerator coefficient's lag
    b = np.zeros(shift + len(num))
    b[shift:] = num / den[0]
    return b, den / den[0]


def _score(b: np.ndarray, a: np.ndarray, valid: Any, poles: np.ndarray) -> tuple[float, float]:
    from scipy.signal import lfilter

    from tendonkit.metrics import fit

    # free run from rest; the first 2,000 samples (20 s, the oscillator's decay is 3.3 s)
    # are left out of the fit so that the unknown initial state does not count
    sim = lfilter(b, a, valid.u[:, 0])
    got = np.sort_complex(np.roots(a))
    got = got[np.abs(got) > 1e-9]
    err = float(np.abs(got - np.sort_complex(poles)).max()) if len(got) == 2 else float("nan")
    return float(fit(valid.y[2000:], sim[2000:, None])[0]), err


def main(argv: list[str] | None = None) -> int:
    from tendonkit.testsystems import lightly_damped_oscillator

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="2000,6000,20000")
    args = p.parse_args(argv)
    valid, poles = lightly_damped_oscillator(20000, seed=151)
    print("| method | N | time [s] | validation fit [%] | pole error |")
    print("|---|---|---|---|---|")
    for n in (int(s) for s in args.sizes.split(",")):
        train, _ = lightly_damped_oscillator(n, seed=51)
        for method, label in METHODS.items():
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                num, den = _estimate(method, train)
                times.append(time.perf_counter() - t0)
            f, err = _score(num, den, valid, poles)  # numerator, denominator
            print(f"| {label} | {n} | {statistics.median(times):.3g} | {f:.2f} | {err:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
