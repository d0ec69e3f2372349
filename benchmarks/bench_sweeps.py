"""Sweeps inside tendonkit on the task engine (issue 19): serial against 2 workers.

The automatic ARX structure (``na = nb = nk = "auto"``: delays per input, then every
``(na, nb)`` up to ``max_order`` by blocked cross-validation) and the SINDYc threshold sweep can
run their candidates on worker processes (``jobs=``, :mod:`tendonkit.parallel`). Both are timed
with ``jobs=1`` (the default) and ``jobs=2`` on the pseudo-random identification record of the
quick demo (paper-like plant, noise on), at its length and at 4x its length, and the results
are checked to be equal.

Usage (repository root, project environment)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_sweeps.py \
        --out benchmarks/results_sweeps.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from tendonkit.dataset import Dataset
from tendonkit.manager import identifiers
from tendonkit.robot.study import run_demo


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write the results as JSON here")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-sweeps-"))
    print("collecting data (the quick demo) ...", file=sys.stderr)
    run_demo(work / "demo", quick=True, progress=False)
    data = Dataset.from_csv(
        work / "demo" / "data" / "train_random.csv",
        inputs=["u1", "u2", "u3", "u4"],
        outputs=["q1", "q2"],
    )
    long = data.concat(data).concat(data).concat(data)
    longer = long.concat(long).concat(long).concat(long)
    reg = identifiers()
    results: dict = {"load_before": os.getloadavg()[0], "cases": []}
    cases = [
        (
            "arx auto (na, nb up to 10)",
            lambda j: reg.get("arx").create(na="auto", nb="auto", jobs=j),
        ),
        ("sindyc threshold sweep", lambda j: reg.get("sindyc").create(jobs=j)),
    ]
    for label, make in cases:
        for name, d in (("record", data), ("4x", long), ("16x", longer)):
            serial, t1 = timed(lambda make=make, d=d: make(1).identify(d))
            pool, t2 = timed(lambda make=make, d=d: make(2).identify(d))
            same = serial.to_dict()["representation"] == pool.to_dict()["representation"]
            row = {
                "sweep": label,
                "data": f"{name}, {d.n_samples} samples",
                "serial_s": t1,
                "jobs2_s": t2,
                "speedup": t1 / t2,
                "same_model": same,
            }
            results["cases"].append(row)
            print(json.dumps(row), file=sys.stderr)
    results["load_after"] = os.getloadavg()[0]
    print(json.dumps(results, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return 0 if all(c["same_model"] for c in results["cases"]) else 1


if __name__ == "__main__":
    raise SystemExit(main())
