"""Model FMU step time: the C backend against the pythonfmu backend (issue 16).

Run from the repository root, one BLAS thread (the README gives the command and results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fmu_step.py --out r.json

The same identified models (SINDYc, N4SID order 6 and ARX(3, 3, 0) of the paper-like plant,
with the joint reconstruction and forward kinematics) are exported with both backends (FMI 2.0)
and driven through the same fmpy loop: ``setReal`` (4 inputs), ``doStep``, ``getReal``
(9 outputs), one 30 ms step at a time.  Reported per step: ``doStep`` alone and the whole
set/step/get iteration (median over the run, after a warm-up), and the archive sizes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

import tendonkit as tk
from tendonkit.fmu.build import export_model_fmu
from tendonkit.fmu.plant import Plant, PlantConfig
from tendonkit.robot.protocol import pseudo_random

INPUTS = ["T1", "T2", "T3", "T4"]
OUTPUTS = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]


def run(path: Path, u: np.ndarray) -> dict[str, float]:
    md = read_model_description(str(path))
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(str(path)),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="bench",
    )
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    vin, vout = [vr[n] for n in INPUTS], [vr[n] for n in OUTPUTS]
    step, loop = [], []
    for k, row in enumerate(u):
        t0 = time.perf_counter()
        fmu.setReal(vin, list(row))
        t1 = time.perf_counter()
        fmu.doStep(k * 0.03, 0.03)
        t2 = time.perf_counter()
        fmu.getReal(vout)
        t3 = time.perf_counter()
        step.append(t2 - t1)
        loop.append(t3 - t0)
    fmu.terminate()
    fmu.freeInstance()
    warm = len(u) // 10
    return {
        "doStep_us": float(np.median(step[warm:]) * 1e6),
        "iteration_us": float(np.median(loop[warm:]) * 1e6),
        "steps": len(u),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=None, help="JSON file for the results")
    parser.add_argument("--steps", type=int, default=20_000, help="C FMU steps")
    parser.add_argument("--python-steps", type=int, default=2_000, help="pythonfmu FMU steps")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    rec = Plant(PlantConfig()).record(pseudo_random(120.0, seed=3).u)
    data = tk.Dataset.from_arrays(
        rec["T_meas"], rec["q"][:, :2], dt=0.03, inputs=INPUTS, outputs=["q1", "q2"]
    )
    models = {
        "sindyc": tk.identify(data, "sindyc"),
        "n4sid": tk.identify(data, "n4sid", order=6),
        "arx": tk.identify(data, "arx", na=3, nb=3, nk=0),
    }
    u = np.tile(rec["T_meas"], (int(np.ceil(args.steps / len(rec["T_meas"]))), 1))
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, model in models.items():
            row: dict[str, Any] = {}
            for backend, n in (("c", args.steps), ("python", args.python_steps)):
                path = Path(tmp) / f"{name}-{backend}.fmu"
                result = export_model_fmu(model, path, backend=backend)
                timing = run(path, u[:n])
                timing["archive_bytes"] = path.stat().st_size
                timing["platforms"] = list(result.platforms)
                row[backend] = timing
            row["doStep_ratio"] = row["python"]["doStep_us"] / row["c"]["doStep_us"]
            row["iteration_ratio"] = row["python"]["iteration_us"] / row["c"]["iteration_us"]
            results[name] = row
            print(
                f"{name:7s} doStep C {row['c']['doStep_us']:7.2f} us, python "
                f"{row['python']['doStep_us']:8.1f} us ({row['doStep_ratio']:.0f}x); "
                f"set/step/get C {row['c']['iteration_us']:6.2f} us, python "
                f"{row['python']['iteration_us']:7.1f} us ({row['iteration_ratio']:.0f}x); "
                f"archive C {row['c']['archive_bytes'] / 1e3:.0f} kB, python "
                f"{row['python']['archive_bytes'] / 1e3:.0f} kB"
            )
    results["machine"] = {
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
    }
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
