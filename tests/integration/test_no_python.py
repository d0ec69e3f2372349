"""Proof that a C model FMU involves no Python (issue 16, point 4).

Each exported C FMU runs in a subprocess whose Python has neither tendonkit nor numpy nor any
other site package: ``python -S -E`` with only the importer's own package folder on its path.
The importers are libcosim (FMI 2.0; libcosim has no FMI 3.0) and Ecos (FMI 2.0 and 3.0), both
C++ masters that load the FMU's binary themselves; the Python packages are thin ctypes
wrappers.  The models cover every representation, every block kind on inputs and on outputs and
every factor function of the schema, plus the robot model with the joint reconstruction and
the forward kinematics, and their outputs must equal ``tendonkit simulate`` to 1e-10.

The importers set the inputs, step and read: what they read after the k-th step is the model's
sample k + 1 with input u[k] still applied.  Inputs that change every other sample make every
second row a sample of ``simulate`` exactly (u[k] = u[k + 1] for even k), models with direct
feedthrough included.

Finally Ecos's own command-line simulator (``ecos simulate``, a C++ program, no Python process
at all) runs the robot FMU from its start values; its CSV (six decimals) must match simulate.
"""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from random_models import KINDS, random_model

import tendonkit as tk
from tendonkit.fmu.build import export_model_fmu
from tendonkit.schema import Model
from tendonkit.simulate import simulate
from tendonkit.terms import FUNCTIONS

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("no_python")]

N = 120
TOL = 1e-10

_RUNNER = r"""
import json, sys
folder, jobs_file, tbb = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.append(folder)  # the importers' packages, nothing else
for name in ("numpy", "tendonkit", "scipy", "pythonfmu", "fmpy"):
    try:
        __import__(name)
    except ImportError:
        continue
    raise SystemExit(f"{name} is importable in the clean importer")
import ctypes
ctypes.CDLL(tbb, mode=ctypes.RTLD_GLOBAL)  # Ecos needs libtbb.so.12
results = []
for job in json.load(open(jobs_file)):
    rows = []
    if job["importer"] == "libcosim":
        from libcosimpy.CosimExecution import CosimExecution
        from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
        from libcosimpy.CosimManipulator import CosimManipulator
        from libcosimpy.CosimObserver import CosimObserver
        from libcosimpy.CosimSlave import CosimLocalSlave
        log_output_level(CosimLogLevel.ERROR)
        ex = CosimExecution.from_step_size(step_size=round(job["dt"] * 1e9))
        index = ex.add_local_slave(CosimLocalSlave(fmu_path=job["path"], instance_name="m"))
        refs = {v.name.decode(): v.reference for v in ex.slave_variables(index)}
        observer = CosimObserver.create_last_value()
        ex.add_observer(observer)
        override = CosimManipulator.create_override()
        ex.add_manipulator(override)
        for row in job["u"]:
            override.slave_real_values(index, [refs[n] for n in job["inputs"]], row)
            if not ex.step(1):
                break
            rows.append(observer.last_real_values(index, [refs[n] for n in job["outputs"]]))
    else:
        from ecospy.EcosSimulation import EcosSimulation
        from ecospy.EcosSimulationStructure import EcosSimulationStructure
        structure = EcosSimulationStructure()
        structure.add_model("m", job["path"])
        sim = EcosSimulation(structure=structure, step_size=job["dt"])
        sim.init()
        for row in job["u"]:
            for name, value in zip(job["inputs"], row):
                sim.set_real(f"m::{name}", value)
            sim.step(1)
            rows.append([sim.get_real(f"m::{n}") for n in job["outputs"]])
        sim.terminate()
    results.append(rows)
print("NUMPY LOADED" if "numpy" in sys.modules else "NO NUMPY")
print("RESULTS " + json.dumps(results))
"""


def _tbb() -> str:
    found = sorted(Path(sys.prefix, "lib").glob("libtbb.so.12*"))
    if not found:
        pytest.fail("Ecos needs libtbb.so.12: pip install tbb (a dev extra)")
    return str(found[0])


def _package(name: str) -> Path:
    """The folder of an installed importer package (not imported here)."""
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin is None:
        pytest.fail(f"{name} is not installed; install the dev extras (pip install {name})")
    return Path(spec.origin).parent


def _covering_models() -> list[Model]:
    """Random models until every kind, block kind (in and out) and function is covered."""
    models: list[Model] = []
    blocks_in: set[str] = set()
    blocks_out: set[str] = set()
    functions: set[str] = set()
    need_blocks = {
        "delay", "dead_zone", "saturation", "play", "first_order_lag", "rate_limit",
        "second_order_section",
    }  # fmt: skip
    for seed in range(500):
        kind = KINDS[seed % len(KINDS)]
        model = random_model(seed, kind, 1.0)
        u = _inputs(model, seed)
        if not np.isfinite(simulate(model, u, initial="model")).all():
            continue
        rep = model.representation
        fns = {f.fn for t in rep.terms for f in t.factors} if rep.terms else set()
        new = (
            ({b.kind for b in model.input_blocks} - blocks_in)
            | ({b.kind for b in model.output_blocks} - blocks_out)
            | (fns - functions)
        )
        if new or kind not in {m.name.removeprefix("random_") for m in models}:
            models.append(model)
            blocks_in |= {b.kind for b in model.input_blocks}
            blocks_out |= {b.kind for b in model.output_blocks}
            functions |= fns
        if blocks_in >= need_blocks and blocks_out >= need_blocks and functions >= set(FUNCTIONS):
            if {m.name.removeprefix("random_") for m in models} >= set(KINDS):
                return models
    pytest.fail("the random models do not cover every block and function")  # pragma: no cover


def _inputs(model: Model, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    steps = rng.normal(0, 1, (N // 2, len(model.inputs))).cumsum(axis=0) * 0.15
    return np.repeat(steps, 2, axis=0)  # u[k] = u[k + 1] for even k


@pytest.fixture(scope="module")
def robot():
    from tendonkit.fmu.plant import Plant
    from tendonkit.robot.protocol import pseudo_random

    rec = Plant().record(pseudo_random(30.0, seed=5).u)
    data = tk.Dataset.from_arrays(
        rec["T_meas"], rec["q"][:, :2], dt=0.03, inputs=["T1", "T2", "T3", "T4"],
        outputs=["q1", "q2"],
    )  # fmt: skip
    model = tk.identify(data, "sindyc")
    return model, np.repeat(rec["T_meas"][:N:2], 2, axis=0)


def _expected(model: Model, u: np.ndarray, kinematics: bool) -> np.ndarray:
    from tendonkit.robot import PAPER_RATIOS
    from tendonkit.robot.kinematics import expand_joints, forward_kinematics

    y = simulate(model, u, initial="model")
    if kinematics:
        q = expand_joints(y, PAPER_RATIOS)
        y = np.hstack([y, q[:, 2:], forward_kinematics(q)])
    return y


def test_c_fmus_run_in_libcosim_and_ecos_without_python_packages(tmp_path, robot):
    models = _covering_models()
    folder = tmp_path / "importers"
    folder.mkdir()
    for package in ("libcosimpy", "ecospy"):
        os.symlink(_package(package), folder / package)
    jobs, expected = [], []
    cases = [(m, _inputs(m, i), False) for i, m in enumerate(models)]
    cases.append((robot[0], robot[1], True))
    for i, (model, u, kinematics) in enumerate(cases):
        outputs = list(model.output_names)
        if kinematics:
            outputs += ["q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]
        for fmi, importer in ((2, "libcosim"), (2, "ecos"), (3, "ecos")):
            path = tmp_path / f"m{i}_{fmi}.fmu"
            if not path.exists():
                export_model_fmu(model, path, kinematics=kinematics, fmi=fmi)
            jobs.append(
                {
                    "importer": importer,
                    "path": str(path),
                    "dt": float(model.dt),
                    "inputs": list(model.input_names),
                    "outputs": outputs,
                    "u": u.tolist(),
                }
            )
            expected.append(_expected(model, u, kinematics))
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}  # nothing of this environment
    r = subprocess.run(
        [sys.executable, "-S", "-E", "-c", _RUNNER, str(folder), str(tmp_path / "jobs.json"),
         _tbb()],
        capture_output=True, text=True, timeout=600, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, (r.stdout + r.stderr)[-3000:]
    assert "NO NUMPY" in r.stdout
    results = json.loads(r.stdout.split("RESULTS ", 1)[1].splitlines()[0])
    for job, rows, ref in zip(jobs, results, expected, strict=True):
        got = np.array(rows)
        assert got.shape == (N, ref.shape[1]), (job["path"], job["importer"], got.shape)
        # row k (read after step k, u[k] applied) is sample k + 1 for even k
        got, want = got[0:-1:2], ref[1::2]
        scale = np.maximum(np.abs(want).max(axis=0), 1e-300)
        err = np.abs(got - want) / scale
        assert err.max() <= TOL, (job["importer"], job["path"], err.max())


def test_ecos_command_line_runs_the_fmu_with_no_python_process(tmp_path, robot):
    """``ecos simulate`` (C++): start values in, CSV out; equal to simulate at CSV precision."""
    model = robot[0]
    binary = tmp_path / "ecos"
    shutil.copy(_package("ecospy") / "binaries" / "ecos", binary)
    binary.chmod(0o755)
    op = model.provenance.details["operating_point"]
    u = np.tile([op[n] for n in model.input_names], (40, 1))
    ref = _expected(model, u, True)
    for fmi in (2, 3):
        path = tmp_path / f"robot{fmi}.fmu"
        export_model_fmu(model, path, fmi=fmi)
        with zipfile.ZipFile(path) as zf:
            so = [n for n in zf.namelist() if n.endswith(".so")]
            assert so and all(b"libpython" not in zf.read(n) for n in so)
        run = tmp_path / f"run{fmi}"
        run.mkdir()
        env = {"PATH": "/usr/bin:/bin", "LD_LIBRARY_PATH": str(Path(_tbb()).parent)}
        r = subprocess.run(
            [str(binary), "simulate", "--path", str(path), "--stepSize", "0.03",
             "--stopTime", str(0.03 * 40), "--noParallel"],
            capture_output=True, text=True, timeout=300, env=env, cwd=run,
        )  # fmt: skip
        assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
        (table,) = list(run.glob("*.csv"))
        with open(table) as f:
            rows = list(csv.reader(f))
        header = [h.strip().removeprefix("instance::").removesuffix("[REAL]") for h in rows[0]]
        data = np.array([[float(x) for x in row] for row in rows[1:]])
        names = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]
        got = data[:, [header.index(n) for n in names]]
        assert got.shape[0] >= 40
        got = got[:40]
        assert np.ptp(ref[:, 0]) > 1e-3  # the model moves from its initial state
        np.testing.assert_allclose(got, ref, rtol=0, atol=1.5e-6)  # six decimals
