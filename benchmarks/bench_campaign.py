"""Campaign engine benchmark (issue 19): a 200-run campaign, serial against 2 workers.

The campaign: 100 plant draws (friction mu_k, force-loop lag tau_f and actuation delay, each drawn
uniformly from the plant spec's range, sensor noise on) x {linear MPC on the demo's N4SID model,
nonlinear MPC on its SINDYc model} x one 60 s petal = 200 co-simulations of 2,000 steps each.
It is run, in one session, serially (``jobs=1``, in this process), on the local process pool
with 2 workers, and on a dask ``LocalCluster`` with 2 workers; every run on one BLAS thread.

Reported: wall time, runs per hour, speed-up over serial, the mean cost of one run inside its
worker, the overhead per run (``workers x wall - sum of run times``, divided by the runs), the
1-minute load average before and after, and a projection for 10,000 runs on 64 workers.
The tables of the three engines are compared (deterministic columns): they must be equal.

Usage (repository root, project environment)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_campaign.py \
        --out benchmarks/results_campaign.json

``--draws 10`` makes a quick check (20 runs).
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

from tendonkit.robot.campaign import run_campaign, spec_from_dict
from tendonkit.robot.study import run_demo


def spec(folder: Path, draws: int, duration: float) -> dict:
    return {
        "campaign": {"name": "bench", "seed": 0, "draws": draws},
        "plant": {
            "effects": ["N"],
            "vary": {"friction_mu_k": "spec", "forcelag_tau": "spec", "delay_s": "spec"},
        },
        "controllers": [
            {"name": "linear MPC (N4SID)", "model": str(folder / "n4sid.json")},
            {"name": "nonlinear MPC (SINDYc)", "model": str(folder / "sindyc.json")},
        ],
        "references": [{"kind": "petal", "duration": duration}],
        "criteria": {
            "require": ["rms_error_true_mrad <= 40", "fallbacks == 0", "bound_violations == 0"]
        },
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=100)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--engines", default="serial,pool,dask")
    ap.add_argument("--out", help="write the results as JSON here")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    print("identifying the models (the quick demo) ...", file=sys.stderr)
    run_demo(work / "demo", quick=True, progress=False)
    s = spec_from_dict(spec(work / "demo", args.draws, args.duration), base_dir=work)
    engines = {
        "serial": {"jobs": 1},
        "pool": {"jobs": 2},
        "dask": {"jobs": 2, "scheduler": "local"},
    }
    results: dict = {"runs": s.n_runs, "duration_s": args.duration, "engines": {}}
    tables = {}
    for name in args.engines.split(","):
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        res = run_campaign(s, work / name, report=False, progress=True, **engines[name])
        wall = time.perf_counter() - t0
        workers = res.summary["timing"]["workers"]
        run_s = [r["wall_s"] for r in res.rows]
        cost = sum(run_s) / len(run_s)
        results["engines"][name] = {
            "workers": workers,
            "wall_s": wall,
            "runs_per_hour": 3600 * s.n_runs / wall,
            "mean_run_s": cost,
            "overhead_per_run_s": (workers * wall - sum(run_s)) / s.n_runs,
            "load_before": load0,
            "load_after": os.getloadavg()[0],
            "pass_rate": res.summary["pass_rate"],
            "retried": len(res.summary["retried"]),
        }
        tables[name] = res.table(deterministic=True)
        print(name, json.dumps(results["engines"][name]), file=sys.stderr)
    names = list(tables)
    results["tables_equal"] = all(tables[n] == tables[names[0]] for n in names)
    e = results["engines"]
    if "serial" in e:
        for n in e:
            e[n]["speedup"] = e["serial"]["wall_s"] / e[n]["wall_s"]
    if "dask" in e:
        d = e["dask"]
        # 10,000 runs on 64 workers: the run cost measured here, plus the per-run overhead the
        # dask engine showed (scheduling, transfer, result handling), plus a cluster start
        per_run = d["mean_run_s"] + max(d["overhead_per_run_s"], 0.0)
        results["projection_64_workers_10000_runs_s"] = 10_000 * per_run / 64 + 30.0
    print(json.dumps(results, indent=1))
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    return 0 if results["tables_equal"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
