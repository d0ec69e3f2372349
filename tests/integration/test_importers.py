"""Exported model FMUs run in two independent FMI importers with fmpy's results.

The importers are libcosim (PyPI ``libcosimpy``, the Open Simulation Platform's C++ master,
via FMI Library) and Ecos (PyPI ``ecospy``, a C++ co-simulation engine with its own FMI
loader); fmpy is the reference.  Both backends are run: the C FMU (the default) and the
pythonfmu FMU, which all three host in this Python process.
Both importers set the inputs, call ``doStep`` and read the outputs after it, so fmpy is
driven in the same order.  They must agree within 1e-9 (rad, m): the three runs execute the same
slave code on the same inputs, so anything above rounding means an importer passed other
inputs, another step size or another start value.

These packages are development dependencies; a missing one is a failure with the install
hint, never a silent skip.  Ecos's ``libecosc.so`` links to ``libtbb.so.12``, which ``ecospy``
does not ship: the PyPI package ``tbb`` provides it and it is loaded before ``ecospy``.
"""

from __future__ import annotations

import ctypes
import importlib
import sys
from pathlib import Path

import numpy as np
import pytest
from fmi_slave import open_slave

import tendonkit as tk
from tendonkit.fmu.build import build_model_fmu
from tendonkit.fmu.plant import Plant
from tendonkit.robot.protocol import pseudo_random

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("test_importers")]

TOL = 1e-9
INPUTS = ["T1", "T2", "T3", "T4"]
OUTPUTS = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]


def _require(module: str, package: str) -> None:
    try:
        importlib.import_module(module)
    except ImportError as exc:
        pytest.fail(
            f"{module} is not importable ({exc}); install the dev extras: pip install {package}"
        )


def _load_tbb() -> None:
    candidates = sorted(Path(sys.prefix, "lib").glob("libtbb.so.12*"))
    if not candidates:
        pytest.fail(
            "Ecos (ecospy) needs libtbb.so.12, which it does not ship; install it with "
            f"'pip install tbb' (looked in {Path(sys.prefix, 'lib')})"
        )
    ctypes.CDLL(str(candidates[0]), mode=ctypes.RTLD_GLOBAL)


@pytest.fixture(scope="session")
def fmus(tmp_path_factory):
    rec = Plant().record(pseudo_random(60.0, seed=3).u)
    train = tk.Dataset.from_arrays(
        rec["T_meas"], rec["q"][:, :2], dt=0.03, inputs=INPUTS, outputs=["q1", "q2"]
    )
    folder = tmp_path_factory.mktemp("importers")
    models = {
        "arx-feedthrough": tk.identify(train, "arx", na=3, nb=3, nk=0),
        "n4sid": tk.identify(train, "n4sid", order=6),
        "sindyc": tk.identify(train, "sindyc"),
    }
    paths = {
        f"{name}-{backend}": build_model_fmu(m, folder / f"{name}-{backend}.fmu", backend=backend)
        for name, m in models.items()
        for backend in ("c", "python")
    }
    return {**paths, "models": models}


@pytest.fixture(scope="session")
def commands():
    rec = Plant().record(pseudo_random(6.0, seed=9).u)
    return rec["T_meas"]


def run_fmpy(path: Path, u: np.ndarray, inputs=INPUTS, outputs=OUTPUTS) -> np.ndarray:
    md, fmu = open_slave(path, "fmpy")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    rows = []
    for k, row in enumerate(u):
        fmu.setReal([vr[n] for n in inputs], list(row))
        fmu.doStep(k * 0.03, 0.03)
        rows.append(fmu.getReal([vr[n] for n in outputs]))
    fmu.terminate()
    fmu.freeInstance()
    return np.array(rows)


def run_libcosim(path: Path, u: np.ndarray, inputs=INPUTS, outputs=OUTPUTS) -> np.ndarray:
    _require("libcosimpy", "libcosimpy")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    execution = CosimExecution.from_step_size(step_size=30_000_000)  # ns
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=str(path), instance_name="m"))
    assert index >= 0, "libcosim could not load the FMU"
    refs = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    override = CosimManipulator.create_override()
    execution.add_manipulator(override)
    rows = []
    for row in u:
        override.slave_real_values(index, [refs[n] for n in inputs], [float(x) for x in row])
        assert execution.step(1), f"libcosim step failed: {execution.status()}"
        rows.append(observer.last_real_values(index, [refs[n] for n in outputs]))
    return np.array(rows)


def run_ecos(path: Path, u: np.ndarray, inputs=INPUTS, outputs=OUTPUTS) -> np.ndarray:
    _load_tbb()
    _require("ecospy", "ecospy")
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure

    structure = EcosSimulationStructure()
    structure.add_model("m", str(path))
    sim = EcosSimulation(structure=structure, step_size=0.03)
    sim.init()
    rows = []
    try:
        for row in u:
            for name, value in zip(inputs, row, strict=True):
                sim.set_real(f"m::{name}", float(value))
            sim.step(1)
            rows.append([sim.get_real(f"m::{name}") for name in outputs])
    finally:
        sim.terminate()
    return np.array(rows)


@pytest.mark.parametrize("backend", ["c", "python"])
@pytest.mark.parametrize("which", ["arx-feedthrough", "n4sid", "sindyc"])
@pytest.mark.parametrize("importer", ["libcosim", "ecos"])
def test_importer_outputs_equal_fmpy(fmus, commands, which, importer, backend):
    path = fmus[f"{which}-{backend}"]
    reference = run_fmpy(path, commands)
    got = (run_libcosim if importer == "libcosim" else run_ecos)(path, commands)
    assert got.shape == reference.shape == (len(commands), len(OUTPUTS))
    assert np.ptp(reference[:, 0]) > 0.01  # the joints move
    np.testing.assert_allclose(got, reference, rtol=0, atol=TOL)


@pytest.mark.parametrize("backend", ["c", "python"])
@pytest.mark.parametrize("which", ["n4sid", "sindyc"])
@pytest.mark.parametrize("importer", ["fmpy", "libcosim", "ecos"])
def test_importer_outputs_equal_tendonkit_simulate(fmus, commands, which, importer, backend):
    """An independent reference: ``simulate`` and the reconstruction, not the slave's own code.

    Importers set ``u(t_k)``, step, then read: without direct feedthrough (these two models)
    the outputs read after the k-th step are the model's sample k + 1.
    """
    from tendonkit.robot.kinematics import expand_joints, forward_kinematics
    from tendonkit.simulate import simulate
    from tendonkit.stepper import feedthrough

    model = fmus["models"][which]
    assert not any(feedthrough(model).values())
    y = simulate(model, commands, initial="model")
    q = expand_joints(y, tk.robot.PAPER_RATIOS)
    expected = np.hstack([y, q[:, 2:], forward_kinematics(q)])[1:]
    run = {"fmpy": run_fmpy, "libcosim": run_libcosim, "ecos": run_ecos}[importer]
    got = run(fmus[f"{which}-{backend}"], commands)[:-1]
    np.testing.assert_allclose(got, expected, rtol=0, atol=TOL)


@pytest.mark.parametrize("importer", ["libcosim", "ecos"])
def test_the_plant_fmu_runs_in_the_importers(tmp_path, commands, importer):
    """The plant FMU (effects on) in libcosim and Ecos gives fmpy's outputs."""
    from tendonkit.fmu.build import build_plant_fmu
    from tendonkit.fmu.plant import PlantConfig
    from tendonkit.fmu.plant_fmu import INPUTS as PLANT_IN
    from tendonkit.fmu.plant_fmu import OUTPUTS as PLANT_OUT

    cfg = PlantConfig(friction_on=True, backlash_on=True, noise_on=True, seed=4)
    path = build_plant_fmu(tmp_path / "plant.fmu", cfg)
    reference = run_fmpy(path, commands, PLANT_IN, PLANT_OUT)
    run = run_libcosim if importer == "libcosim" else run_ecos
    got = run(path, commands, PLANT_IN, PLANT_OUT)
    assert np.ptp(reference[:, 0]) > 0.01
    np.testing.assert_allclose(got, reference, rtol=0, atol=TOL)


_WITHOUT_TENDONKIT = r"""
import sys
sys.modules["tendonkit"] = None  # the importer's Python has no tendonkit
path, importer = sys.argv[1], sys.argv[2]
if importer == "fmpy":
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    messages = []
    md = read_model_description(path)
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="m")
    fmu.instantiate(loggingOn=True, callbacks=None)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    try:
        fmu.doStep(0.0, 0.03)
        print("STEP ACCEPTED")
    except Exception as exc:
        print("STEP REFUSED", exc)
    fmu.terminate()
    fmu.freeInstance()
elif importer == "ecos":
    import ctypes
    ctypes.CDLL(sys.argv[3], mode=ctypes.RTLD_GLOBAL)  # libtbb.so.12 (see _load_tbb)
    from ecospy.EcosSimulation import EcosSimulation
    from ecospy.EcosSimulationStructure import EcosSimulationStructure
    structure = EcosSimulationStructure()
    structure.add_model("m", path)
    sim = EcosSimulation(structure=structure, step_size=0.03)
    sim.init()
    sim.step(1)  # Ecos does not stop on a refused step; the outputs say it
    value = sim.get_real("m::q1")
    print("STEP REFUSED (outputs NaN)" if value != value else f"STEP ACCEPTED q1={value}")
else:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimSlave import CosimLocalSlave
    execution = CosimExecution.from_step_size(step_size=30_000_000)
    index = execution.add_local_slave(CosimLocalSlave(fmu_path=path, instance_name="m"))
    print("INDEX", index)
    print("STEP REFUSED" if not execution.step(1) else "STEP ACCEPTED")
print("ALIVE")
"""


@pytest.mark.parametrize("importer", ["fmpy", "libcosim", "ecos"])
def test_an_importer_without_tendonkit_gets_a_message_not_a_crash(fmus, importer):
    """The slave still instantiates, names what is missing and refuses to step (issue 16).

    Before, the slave module failed to import, pythonfmu returned no instance, fmpy raised
    "Failed to instantiate model" and libcosim died of a segmentation fault.
    """
    import subprocess

    tbb = ""
    if importer == "libcosim":
        _require("libcosimpy", "libcosimpy")
    if importer == "ecos":
        _load_tbb()
        _require("ecospy", "ecospy")
        tbb = str(sorted(Path(sys.prefix, "lib").glob("libtbb.so.12*"))[0])
    r = subprocess.run(
        [sys.executable, "-c", _WITHOUT_TENDONKIT, str(fmus["n4sid-python"]), importer, tbb],
        capture_output=True,
        text=True,
        timeout=300,
    )
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "ALIVE" in r.stdout, out[-3000:]  # no segfault
    assert "STEP REFUSED" in r.stdout, out[-3000:]
    if importer == "fmpy":
        assert "needs tendonkit" in out and "cannot be imported" in out, out[-3000:]
