"""Closed-loop MPC co-simulation speed: 60 s petal on the plant FMU, design path vs fast path.

For each plant (nominal: petal at 8 cm/s; paper-like preset: petal at 2.5 cm/s; both with
sensor noise) the script collects training data through the plant FMU, identifies an N4SID
(order 8, horizon 30) and a SINDYc model — as ``tests/integration/test_mpc_cosim.py`` does — and runs a
60 s petal co-simulation with

* the linear MPC (N4SID model) and the nonlinear MPC (SINDYc model), tuned settings of
  :data:`tendonkit.robot.cosim.DEFAULTS` (horizon 20, Clarabel);
* on the *design path* (cvxpy ``problem.solve`` every step, DPP re-use) and on the *fast path*
  (cvxpy's parameter-affine data fed to a persistent Clarabel solver);
* and the open-loop kinematic controller for the tracking baseline.

Reported per run: QP solve time (median / p99 / max, ms), the controller's whole step (wall
and thread CPU time), deadline misses (> 30 ms), fallbacks, input-bound violations, the loop's
wall-clock and process CPU time, the time inside the plant FMU, and the real-time factor
(60 s / loop wall time; also 60 s / loop CPU time, which is insensitive to other jobs on a
shared machine), plus the RMS true joint errors.  The load average is recorded before and
after every run.

Targets (issue 5): linear MPC solve median <= 2 ms and p99 <= 5 ms; nonlinear MPC p99 <= 15 ms
(checked on the whole step, linearisation included); the whole closed loop >= 20x faster than
real time (fast path).

Usage::

    python benchmarks/bench_mpc_cosim.py [--duration 60] [--plants nominal,paper_like]
        [--wait-quiet 1.0] [--json results.json]

Not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

PETALS = {"nominal": 0.08, "paper_like": 0.025}
SEED = 7


class Timed:
    """Wraps a controller and records the thread CPU time of each step."""

    def __init__(self, ctrl: Any) -> None:
        self.ctrl = ctrl
        self.horizon = ctrl.horizon
        self.output_names = ctrl.output_names
        self.cpu: list[float] = []

    def reset(self, u0: Any = None, y0: Any = None) -> None:
        self.ctrl.reset(u0, y0)

    def step(self, y: Any, r: Any) -> Any:
        c0 = time.thread_time()
        res = self.ctrl.step(y, r)
        self.cpu.append(time.thread_time() - c0)
        return res


def wait_quiet(limit: float, timeout: float = 900.0) -> float:
    """Wait (up to ``timeout`` s) until the 1-minute load average is below ``limit``."""
    t0 = time.time()
    while os.getloadavg()[0] > limit and time.time() - t0 < timeout:
        time.sleep(10.0)
    return os.getloadavg()[0]


def models_for(plant: str, folder: Path) -> tuple[Path, dict[str, Any]]:
    """Build the noisy plant FMU, collect training data, identify N4SID and SINDYc."""
    import tendonkit as tk
    from tendonkit.dataset import Dataset
    from tendonkit.fmu.build import build_plant_fmu
    from tendonkit.fmu.plant import PlantConfig
    from tendonkit.robot.collect import collect
    from tendonkit.robot.protocol import circles, pseudo_random

    fmu = build_plant_fmu(folder / f"{plant}.fmu", PlantConfig.preset(plant).replace(noise_on=True))
    parts = [
        circles(radii=[0.02, 0.04, 0.06, 0.08, 0.10, 0.12], laps=1),
        pseudo_random(120.0, seed=100 + SEED),
    ]
    recs = [collect(p, plant=fmu, seed=10 * SEED + i) for i, p in enumerate(parts)]
    sets = [r.to_dataset(inputs=("u1", "u2", "u3", "u4")) for r in recs]
    train = Dataset(
        inputs=sets[0].inputs,
        outputs=sets[0].outputs,
        experiments=tuple(s.experiments[0] for s in sets),
        dt=0.03,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        models = {
            "linear": tk.identify(train, "n4sid", order=8, horizon=30),
            "nonlinear": tk.identify(train, "sindyc"),
        }
    return fmu, models


def stats(ms: np.ndarray) -> dict[str, float]:
    return {
        "median": float(np.median(ms)),
        "p99": float(np.percentile(ms, 99)),
        "max": float(np.max(ms)),
    }


def bench(plant: str, duration: float, folder: Path, quiet: float | None) -> list[dict[str, Any]]:
    from tendonkit.robot.cosim import (
        ControllerSettings,
        make_controller,
        make_reference,
        open_loop,
        run,
    )

    fmu, models = models_for(plant, folder)
    ref = make_reference("petal", duration=duration, speed=PETALS[plant])
    params = {"seed": 1000 + SEED}
    ol = open_loop(fmu, ref, parameters=params)
    rows = [
        {
            "plant": plant,
            "controller": "open loop",
            "path": "-",
            "rms_true_mrad": (1e3 * ol.rms_error_true).round(2).tolist(),
            "realtime_factor": ol.summary()["realtime_factor"],
        }
    ]
    for kind in ("linear", "nonlinear"):
        for fast in (False, True):
            if quiet is not None:
                wait_quiet(quiet)
            t0 = time.perf_counter()
            ctrl = Timed(make_controller(models[kind], ControllerSettings(fast=fast)))
            setup = time.perf_counter() - t0
            load_before = os.getloadavg()[0]
            res = run(fmu, ref, ctrl, parameters=params, name=kind)
            s = res.summary()
            rows.append(
                {
                    "plant": plant,
                    "controller": f"{kind} MPC",
                    "path": "fast (direct Clarabel)" if fast else "design (cvxpy solve)",
                    "setup_s": setup,
                    "solve_ms": s["solve_time_ms"],
                    "step_ms": s["step_time_ms"],
                    "step_cpu_ms": stats(1e3 * np.array(ctrl.cpu)),
                    "deadline_misses": s["deadline_misses"],
                    "fallbacks": s["fallbacks"],
                    "violations": s["input_bound_violations"],
                    "wall_s": s["wall_time_s"],
                    "cpu_s": s["cpu_time_s"],
                    "plant_s": s["plant_time_s"],
                    "realtime_factor": s["realtime_factor"],
                    "realtime_factor_cpu": ref.duration / s["cpu_time_s"],
                    "rms_true_mrad": (1e3 * res.rms_error_true).round(2).tolist(),
                    "load_before": load_before,
                    "load_after": os.getloadavg()[0],
                }
            )
            print(_line(rows[-1]), flush=True)
    return rows


def _line(r: dict[str, Any]) -> str:
    if "solve_ms" not in r:
        return f"| {r['plant']} | open loop | – | – | – | – | – | – | {r['rms_true_mrad']} |"
    s, st, c = r["solve_ms"], r["step_ms"], r["step_cpu_ms"]
    return (
        f"| {r['plant']} | {r['controller']}, {r['path']} | "
        f"{s['median']:.2f} / {s['p99']:.2f} / {s['max']:.2f} | "
        f"{st['median']:.2f} / {st['p99']:.2f} / {st['max']:.2f} | "
        f"{c['median']:.2f} / {c['p99']:.2f} | {r['deadline_misses']} / {r['fallbacks']} / "
        f"{r['violations']} | {r['wall_s']:.2f} / {r['cpu_s']:.2f} / {r['plant_s']:.2f} | "
        f"{r['realtime_factor']:.1f} / {r['realtime_factor_cpu']:.1f} | {r['rms_true_mrad']} | "
        f"{r['load_before']:.1f}→{r['load_after']:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="petal length, s (60)")
    parser.add_argument("--plants", default="nominal,paper_like", help="comma separated")
    parser.add_argument(
        "--wait-quiet",
        type=float,
        help="before each run wait (up to 15 min) for a 1-minute load average below this",
    )
    parser.add_argument("--json", help="write all rows here")
    args = parser.parse_args()
    import clarabel
    import cvxpy

    print(
        f"{os.cpu_count()} CPUs ({platform.processor() or platform.machine()}), Python "
        f"{platform.python_version()}, numpy {np.__version__}, cvxpy {cvxpy.__version__}, "
        f"clarabel {clarabel.__version__}; load average "
        + ", ".join(f"{v:.1f}" for v in os.getloadavg())
    )
    print(
        "| plant | controller, path | solve ms med / p99 / max | step ms med / p99 / max | "
        "step CPU ms med / p99 | misses / fallbacks / violations | loop wall / CPU / plant s "
        "| real time × (wall / CPU) | RMS true q1, q2 mrad | load |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for plant in args.plants.split(","):
            plant_rows = bench(plant.strip(), args.duration, Path(tmp), args.wait_quiet)
            print(_line(plant_rows[0]))
            rows += plant_rows
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    fast = [r for r in rows if r.get("path", "").startswith("fast")]
    lin = [r for r in fast if r["controller"].startswith("linear")]
    nl = [r for r in fast if r["controller"].startswith("nonlinear")]
    print("\nTargets (fast path):")
    for r in lin:
        s = r["solve_ms"]
        print(
            f"  {r['plant']}: linear solve median {s['median']:.2f} ms (<= 2), p99 "
            f"{s['p99']:.2f} ms (<= 5): {'met' if s['median'] <= 2 and s['p99'] <= 5 else 'NOT met'}"
        )
    for r in nl:
        p99 = r["step_ms"]["p99"]
        print(
            f"  {r['plant']}: nonlinear step p99 {p99:.2f} ms (<= 15): {'met' if p99 <= 15 else 'NOT met'}"
        )
    for r in fast:
        rt = r["realtime_factor"]
        print(
            f"  {r['plant']} {r['controller']}: {rt:.1f}x real time (>= 20): "
            f"{'met' if rt >= 20 else 'NOT met'} (CPU-time based {r['realtime_factor_cpu']:.1f}x)"
        )


if __name__ == "__main__":
    main()
