"""Model FMU step time: the C backend against the pythonfmu backend (issue 16).

Run from the repository root, one BLAS thread (the README gives the command and results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_fmu_step.py --out r.json

The same identified models (SINDYc, N4SID order 6 and ARX(3, 3, 0) of the paper-like plant,
with the joint reconstruction and forward kinematics) are exported with both backends (FMI 2.0)
and driven through the same fmpy loop: ``setReal`` (4 inputs), ``doStep``, ``getReal``
(9 outputs), one 30 ms step at a time.  Reported per step: ``doStep`` alone and the whole
set/step/get iteration (median over the run, after a warm-up), and the archive sizes.

Three loops: a minimal C master (``fmu_step_harness.c``: dlopen, instantiate, then
set/doStep/get, timed with ``clock_gettime``; the pythonfmu binary embeds the interpreter of
this environment), which shows what each FMU costs an importer written in C or C++; fmpy's ``FMU2Slave`` methods (what a user writes; each call passes through fmpy's
Python wrapper, about 2 µs), and the same FMU's ``fmi2SetReal``/``fmi2DoStep``/``fmi2GetReal``
called directly through ctypes with preallocated buffers (what ``PlantSession`` does), which
leaves the cost of the FMU itself.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import sysconfig
import tempfile
import time
import zipfile
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
    # the same FMU's functions through ctypes, no fmpy wrapper
    import ctypes

    dll, comp = fmu.dll, fmu.component
    set_real, do_step, get_real = dll.fmi2SetReal, dll.fmi2DoStep, dll.fmi2GetReal
    do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    do_step.restype = ctypes.c_int
    vin_c = (ctypes.c_uint * len(vin))(*vin)
    vout_c = (ctypes.c_uint * len(vout))(*vout)
    bin_c = (ctypes.c_double * len(vin))()
    bout_c = (ctypes.c_double * len(vout))()
    raw_step, raw_loop = [], []
    t = len(u) * 0.03
    for row in u:
        bin_c[:] = row.tolist()
        t0 = time.perf_counter()
        set_real(comp, vin_c, len(vin), bin_c)
        t1 = time.perf_counter()
        status = do_step(comp, t, 0.03, 1)
        t2 = time.perf_counter()
        get_real(comp, vout_c, len(vout), bout_c)
        t3 = time.perf_counter()
        assert status == 0, status
        t += 0.03
        raw_step.append(t2 - t1)
        raw_loop.append(t3 - t0)
    fmu.terminate()
    fmu.freeInstance()
    warm = len(u) // 10
    return {
        "doStep_us": float(np.median(step[warm:]) * 1e6),
        "iteration_us": float(np.median(loop[warm:]) * 1e6),
        "raw_doStep_us": float(np.median(raw_step[warm:]) * 1e6),
        "raw_iteration_us": float(np.median(raw_loop[warm:]) * 1e6),
        "steps": len(u),
    }


def harness() -> Path:
    """Compile the C master of ``fmu_step_harness.c`` (system C compiler, fmpy's FMI headers)."""
    import fmpy

    out = Path(tempfile.mkdtemp()) / "fmu_step_harness"
    headers = Path(fmpy.__file__).parent / "c-code"
    source = Path(__file__).with_name("fmu_step_harness.c")
    subprocess.run(
        ["cc", "-O2", "-I", str(headers), "-o", str(out), str(source), "-ldl"], check=True
    )
    return out


def run_harness(binary: Path, path: Path, steps: int) -> tuple[float, float]:
    """Nanoseconds per ``doStep`` and per set/step/get iteration in the C master."""
    folder = Path(tempfile.mkdtemp())
    with zipfile.ZipFile(path) as zf:
        zf.extractall(folder)
    md = read_model_description(str(folder))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    (lib,) = (folder / "binaries" / "linux64").glob("*.so")
    env = dict(os.environ)
    env["HARNESS_PRELOAD"] = str(
        Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    )  # a pythonfmu binary runs its slave in an embedded interpreter
    env["PATH"] = f"{Path(sys.executable).parent}:{env.get('PATH', '')}"
    r = subprocess.run(
        [str(binary), str(lib), (folder / "resources").as_uri(), md.guid, "0.03", str(steps),
         *[str(vr[n]) for n in INPUTS], "--", *[str(vr[n]) for n in OUTPUTS]],
        capture_output=True, text=True, env=env, check=True,
    )  # fmt: skip
    step_ns, loop_ns = (float(x) for x in r.stdout.split())
    return step_ns, loop_ns


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
    master = harness()
    with tempfile.TemporaryDirectory() as tmp:
        for name, model in models.items():
            row: dict[str, Any] = {}
            for backend, n in (("c", args.steps), ("python", args.python_steps)):
                path = Path(tmp) / f"{name}-{backend}.fmu"
                result = export_model_fmu(model, path, backend=backend)
                timing = run(path, u[:n])
                step_ns, loop_ns = run_harness(master, path, 10 * n)
                timing["c_master_doStep_us"] = step_ns / 1e3
                timing["c_master_iteration_us"] = loop_ns / 1e3
                timing["archive_bytes"] = path.stat().st_size
                timing["platforms"] = list(result.platforms)
                row[backend] = timing
            keys = ("doStep_us", "iteration_us", "raw_doStep_us", "raw_iteration_us")
            for key in (*keys, "c_master_doStep_us", "c_master_iteration_us"):
                row[key.replace("_us", "_ratio")] = row["python"][key] / row["c"][key]
            results[name] = row
            c, p = row["c"], row["python"]
            print(
                f"{name:7s} fmpy methods: doStep C {c['doStep_us']:6.2f} us, python "
                f"{p['doStep_us']:7.1f} us ({row['doStep_ratio']:.0f}x), set/step/get "
                f"{row['iteration_ratio']:.0f}x | ctypes: doStep C {c['raw_doStep_us']:5.2f} us, "
                f"python {p['raw_doStep_us']:7.1f} us ({row['raw_doStep_ratio']:.0f}x), "
                f"set/step/get C {c['raw_iteration_us']:5.2f} us, python "
                f"{p['raw_iteration_us']:7.1f} us ({row['raw_iteration_ratio']:.0f}x) | C master: "
                f"doStep C {c['c_master_doStep_us']:5.3f} us, python "
                f"{p['c_master_doStep_us']:6.1f} us ({row['c_master_doStep_ratio']:.0f}x) | archive "
                f"C {c['archive_bytes'] / 1e3:.0f} kB, python {p['archive_bytes'] / 1e3:.0f} kB"
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
