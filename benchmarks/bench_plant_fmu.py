"""Plant FMU speed: the full 454 s circle protocol (15 173 frames of 30 ms) under fmpy.

Measures, each as the best of ``--repeat`` runs (the machine is shared, so the best run is the
least disturbed one; the median is printed too):

* ``plant.run`` — the plant alone, vectorised over the whole record (its upper bound);
* ``plant.step`` — the plant alone, one frame per call (what an FMU step must do);
* ``fmu raw`` — the FMU through fmpy's ctypes functions with pre-built value-reference arrays
  (:class:`tendonkit.robot.collect.PlantSession`, as ``tendonkit collect`` drives it), with the time
  split into ``fmi2SetReal``, ``fmi2DoStep`` and ``fmi2GetReal``;
* ``fmu fmpy`` — the same loop through fmpy's convenience methods (``setReal`` / ``doStep`` /
  ``getReal`` with Python lists), as typical user code does;
* ``simulate_fmu`` — fmpy's own simulation loop with the commands as an input table.

Real-time factor = simulated seconds / wall-clock seconds.  Usage::

    python benchmarks/bench_plant_fmu.py [--repeat 5] [--effects] [--json out.json]

``--effects`` adds single-effect plants (friction, force lag).  Not a test.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np


def _best(times: list[float]) -> tuple[float, float]:
    return min(times), statistics.median(times)


def bench_plant(config: Any, u: np.ndarray, repeat: int) -> dict[str, Any]:
    from tendonkit.fmu.plant import Plant

    plant = Plant(config)
    run, step = [], []
    for _ in range(repeat):
        plant.reset()
        t0 = time.perf_counter()
        plant.run(u)
        run.append(time.perf_counter() - t0)
        plant.reset()
        t0 = time.perf_counter()
        for row in u:
            plant.step(row)
        step.append(time.perf_counter() - t0)
    return {"plant.run": _best(run), "plant.step": _best(step)}


def bench_fmu_raw(path: Path, u: np.ndarray, repeat: int) -> dict[str, Any]:
    from tendonkit.robot.collect import PlantSession

    totals, parts = [], []
    for _ in range(repeat):
        with PlantSession(path) as s:
            c, vin, vout, bin_, bout = s._component, s._vr_in, s._vr_out, s._buf_in, s._buf_out
            set_real, do_step, get_real = s._set_real, s._do_step, s._get_real
            u_view, h, n_out = s._u, s.step_size, len(s.outputs)
            y = np.empty((len(u), n_out))
            t_set = t_step = t_get = 0.0
            clock = time.perf_counter
            t0 = clock()
            for k in range(len(u)):
                a = clock()
                u_view[:] = u[k]
                set_real(c, vin, 4, bin_)
                b = clock()
                do_step(c, k * h, h, 1)
                d = clock()
                get_real(c, vout, n_out, bout)
                y[k] = s.outputs
                e = clock()
                t_set += b - a
                t_step += d - b
                t_get += e - d
            total = clock() - t0
        totals.append(total)
        parts.append((t_set, t_step, t_get))
        # Without the per-call clocks (their own cost is ~0.3 µs per frame):
        with PlantSession(path) as s:
            t0 = time.perf_counter()
            for row in u:
                s.step(row)
            totals[-1] = min(totals[-1], time.perf_counter() - t0)
    best = int(np.argmin(totals))
    return {"fmu raw": _best(totals), "split": parts[best]}


def bench_fmu_fmpy(path: Path, u: np.ndarray, repeat: int) -> dict[str, Any]:
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from tendonkit.robot.collect import INPUTS, OUTPUTS

    md = read_model_description(str(path))
    refs = {v.name: v.valueReference for v in md.modelVariables}
    vin, vout = [refs[n] for n in INPUTS], [refs[n] for n in OUTPUTS]
    folder = extract(str(path))
    times = []
    for _ in range(repeat):
        fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=folder,
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="bench",
        )
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        rows = u.tolist()
        t0 = time.perf_counter()
        for k, row in enumerate(rows):
            fmu.setReal(vin, row)
            fmu.doStep(k * 0.03, 0.03)
            fmu.getReal(vout)
        times.append(time.perf_counter() - t0)
        fmu.terminate()
        fmu.freeInstance()
    return {"fmu fmpy": _best(times)}


def bench_simulate(path: Path, u: np.ndarray, repeat: int) -> dict[str, Any]:
    from fmpy import simulate_fmu

    from tendonkit.robot.collect import INPUTS, OUTPUTS

    n = len(u)
    signals = np.zeros(n, dtype=[("time", float)] + [(name, float) for name in INPUTS])
    signals["time"] = np.arange(n) * 0.03
    for k, name in enumerate(INPUTS):
        signals[name] = u[:, k]
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        simulate_fmu(
            str(path),
            stop_time=n * 0.03,
            output_interval=0.03,
            input=signals,
            output=list(OUTPUTS),
        )
        times.append(time.perf_counter() - t0)
    return {"simulate_fmu": _best(times)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--effects", action="store_true", help="also friction and force lag")
    parser.add_argument("--json", help="write the results here")
    args = parser.parse_args()

    from tendonkit.fmu.build import build_plant_fmu
    from tendonkit.fmu.plant import PlantConfig
    from tendonkit.robot.protocol import circles

    u = circles().u
    n = len(u)
    simulated = n * 0.03
    configs = {"nominal": PlantConfig()}
    if args.effects:
        configs["friction (A)"] = PlantConfig(friction_on=True)
        configs["force lag (F)"] = PlantConfig(forcelag_on=True)
    results: dict[str, Any] = {
        "frames": n,
        "simulated_s": simulated,
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "plants": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        for label, config in configs.items():
            path = build_plant_fmu(Path(tmp) / f"{len(results['plants'])}.fmu", config)
            res: dict[str, Any] = {}
            res.update(bench_plant(config, u, args.repeat))
            res.update(bench_fmu_raw(path, u, args.repeat))
            res.update(bench_fmu_fmpy(path, u, max(1, args.repeat // 2)))
            if label == "nominal":
                res.update(bench_simulate(path, u, max(1, args.repeat // 2)))
            results["plants"][label] = res
    print(f"circle protocol: {n} frames = {simulated:.1f} s simulated; best (median) of runs\n")
    header = f"{'plant':<14} {'path':<13} {'wall s':>14} {'us/frame':>9} {'x real time':>12}"
    print(header)
    print("-" * len(header))
    for label, res in results["plants"].items():
        for key in ("plant.run", "plant.step", "fmu raw", "fmu fmpy", "simulate_fmu"):
            if key not in res:
                continue
            best, med = res[key]
            print(
                f"{label:<14} {key:<13} {best:>6.3f} ({med:5.3f}) {best / n * 1e6:>9.1f} "
                f"{simulated / best:>12.0f}"
            )
        t_set, t_step, t_get = (t / n * 1e6 for t in res["split"])
        plant_step = res["plant.step"][0] / n * 1e6
        print(
            f"{'':<14} split: fmi2SetReal {t_set:.1f} us, fmi2DoStep {t_step:.1f} us "
            f"(Plant.step alone {plant_step:.1f} us), fmi2GetReal {t_get:.1f} us per frame"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
