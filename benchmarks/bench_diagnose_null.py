"""diagnose's false alarms: how often a cause is named on plants that have none.

Run from the repository root, one BLAS thread (benchmarks/README.md gives the results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_diagnose_null.py --jobs 2

A linear plant with no hidden effect: a second-order system (natural frequency 0.05 cycles
per sample, damping ratio 0.3) driven by a band-limited random input; its output carries
noise at ``--noise`` (30 %) of its standard deviation, coloured by an AR(1) filter of
coefficient ``--colour`` (0.97: slow, like a model error that persists).  Two training and two
validation experiments of ``--samples`` each (defaults 400 and 100: the coupled drives'
records, whose validation data are a few autocorrelation times long), fresh input and noise
per seed.  ``diagnose(train, valid)`` with nothing set; a seed *alarms* when it names any
cause.  The free-run test's batches are fewer than five autocorrelation-time multiples there,
which is where its degrees of freedom matter (docs/diagnose.md, "Statistics").

The level asked for is ``alpha`` = 1 % per test; the family of effects is Holm-adjusted, so the
rate of named causes on such plants should stay near or below it.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import butter, lfilter

from tendonkit.dataset import Dataset, Experiment
from tendonkit.parallel import run_tasks


def record(seed: int, n: int, noise: float, colour: float) -> Experiment:
    """One experiment of the plant: input, noisy output."""
    rng = np.random.default_rng(seed)
    burn = max(200, int(5 / (1 - colour)))  # five time constants of the noise's colour
    u = lfilter(*butter(2, 0.1), rng.standard_normal(n + burn))
    w, z = 2 * np.pi * 0.05, 0.3
    a1, a2 = 2 * np.exp(-z * w) * np.cos(w * np.sqrt(1 - z * z)), -np.exp(-2 * z * w)
    y = lfilter([0.0, 1.0 - a1 - a2], [1.0, -a1, -a2], u)[burn:]
    u = u[burn:]
    e = lfilter([1.0], [1.0, -colour], rng.standard_normal(n + burn))[burn:]
    y = y + noise * y.std() * e / e.std()
    return Experiment(t=np.arange(n, dtype=float), u=u[:, None], y=y[:, None], name=f"r{seed}")


def case(shared: tuple[int, int, float, float], seed: int) -> dict[str, Any]:
    """One diagnosis at default options."""
    from tendonkit.diagnose import diagnose

    n_train, n_valid, noise, colour = shared

    def data(first: int, n: int) -> Dataset:
        exps = tuple(record(10 * seed + first + i, n, noise, colour) for i in range(2))
        return Dataset(inputs=("u",), outputs=("y",), experiments=exps, dt=1.0)

    t0 = time.perf_counter()
    d = diagnose(data(0, n_train), data(5, n_valid))
    return {
        "seed": seed,
        "causes": list(d.causes),
        "alarm": d.cause != "none",
        "findings": [
            {"effect": f.effect, "gain": f.gain, "p_adjusted": f.p_adjusted} for f in d.findings[:3]
        ],
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=300, help="number of seeds (from 1)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--samples", default="400,100", help="training,validation samples")
    parser.add_argument("--noise", type=float, default=0.3, help="noise / output std")
    parser.add_argument("--colour", type=float, default=0.97, help="AR(1) coefficient")
    parser.add_argument("--out", default=None, help="JSON file for the results")
    args = parser.parse_args()
    n_train, n_valid = (int(s) for s in args.samples.split(","))
    shared = (n_train, n_valid, args.noise, args.colour)
    seeds = list(range(1, args.seeds + 1))
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = [{} for _ in seeds]
    for o in run_tasks(case, seeds, jobs=args.jobs, shared=shared, progress=True, desc="seeds"):
        if o.error is not None:
            raise SystemExit(f"seed {seeds[o.index]} failed: {o.error}")
        rows[o.index] = o.value
    alarms = [r for r in rows if r["alarm"]]
    for r in alarms:
        top = ", ".join(
            f"{f['effect']} {f['gain']:+.2f} ({f['p_adjusted']:.0e})" for f in r["findings"]
        )
        print(f"seed {r['seed']}: causes {', '.join(r['causes'])} ({top})")
    print(f"alarms: {len(alarms)} of {len(rows)} ({100 * len(alarms) / len(rows):.1f} %)")
    if args.out:
        machine = {"load_before": load, "load_after": os.getloadavg()[0]}
        machine["wall_s"] = time.perf_counter() - t0
        out = {"rows": rows, "machine": machine, "arguments": vars(args)}
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
