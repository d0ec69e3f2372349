"""A model FMU exported by tendonkit 0.1 (before the move into rooms) still simulates.

Its slave imports the 0.1 module paths (``tendonkit.kinematics``, ``tendonkit.robot``) at run
time; ``tendonkit._compat`` keeps them importable for one release (tests/fmu/data/README.md).
"""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmi_slave import open_slave

from tendonkit.robot import PAPER_RATIOS
from tendonkit.robot.kinematics import expand_joints, forward_kinematics
from tendonkit.schema import Model
from tendonkit.simulate import simulate

LEGACY = Path(__file__).parent / "data" / "legacy-0.1.0-model.fmu"
OUTPUTS = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]


def _inputs(n: int = 120) -> np.ndarray:
    rng = np.random.default_rng(5)
    return 105.0 + 40.0 * np.cumsum(rng.normal(scale=0.2, size=(n, 4)), axis=0).clip(-2, 2)


def _run(path: Path, u: np.ndarray) -> np.ndarray:
    """fmpy, FMI co-simulation order: set inputs, read outputs, doStep."""
    md, fmu = open_slave(path, "legacy")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    dt = float(md.defaultExperiment.stepSize)
    vin = [vr[n] for n in ("F1", "F2", "F3", "F4")]
    vout = [vr[n] for n in OUTPUTS]
    rows = []
    try:
        for k, row in enumerate(u):
            fmu.setReal(vin, list(row))
            rows.append(fmu.getReal(vout))
            fmu.doStep(k * dt, dt)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    return np.array(rows)


def _expected(u: np.ndarray) -> np.ndarray:
    with zipfile.ZipFile(LEGACY) as z:
        model = Model.from_json(z.read("resources/model.json").decode())
        config = json.loads(z.read("resources/model_fmu.json"))
    assert config["kinematics"]
    y = simulate(model, u, initial="model")
    q = expand_joints(y, PAPER_RATIOS)
    return np.hstack([y, q[:, 2:], forward_kinematics(q)])


def test_the_archive_is_from_0_1_and_imports_its_old_paths():
    with zipfile.ZipFile(LEGACY) as z:
        slave = z.read("resources/model_fmu.py").decode()
        description = z.read("modelDescription.xml").decode()
    assert "from tendonkit.kinematics import" in slave
    # the model's version attribute is tendonkit's at export (the tool that packed it: PythonFMU)
    assert ET.fromstring(description).get("version") == "0.1.0"


def test_a_0_1_model_fmu_simulates_like_tendonkit_simulate():
    u = _inputs()
    y = _run(LEGACY, u)
    assert np.all(np.isfinite(y))
    np.testing.assert_allclose(y, _expected(u), rtol=1e-9, atol=1e-12)


def test_a_0_1_model_fmu_through_fmpy_simulate_fmu():
    from fmpy import read_model_description, simulate_fmu

    u = _inputs()
    n = len(u)
    dt = float(read_model_description(str(LEGACY)).defaultExperiment.stepSize)
    signals = np.zeros(n, dtype=[("time", float)] + [(f"F{i}", float) for i in range(1, 5)])
    signals["time"] = np.arange(n) * dt
    for i in range(4):
        signals[f"F{i + 1}"] = u[:, i]
    res = simulate_fmu(
        str(LEGACY),
        start_time=0.0,
        stop_time=(n - 1) * dt,
        output_interval=dt,
        input=signals,
        output=OUTPUTS,
    )
    y = np.column_stack([res[name] for name in OUTPUTS])
    assert y.shape == (n, len(OUTPUTS))
    np.testing.assert_allclose(y, _expected(u), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("python_warnings", ["default", "error::DeprecationWarning:__main__"])
def test_a_0_1_model_fmu_in_a_fresh_interpreter(tmp_path, python_warnings):
    # The slave's `import tendonkit.kinematics` is the first tendonkit import of the process.
    u = _inputs(40)
    np.save(tmp_path / "u.npy", u)
    code = (
        "import sys, numpy as np\n"
        f"sys.path[:0] = [{str(Path(__file__).parent)!r}, {str(Path(__file__).parents[1])!r}]\n"
        "from test_legacy_fmu import _run, LEGACY\n"
        f"np.save({str(tmp_path / 'y.npy')!r}, _run(LEGACY, np.load({str(tmp_path / 'u.npy')!r})))\n"
    )
    r = subprocess.run(
        [sys.executable, "-W", python_warnings, "-c", code],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(np.load(tmp_path / "y.npy"), _expected(u), rtol=1e-9, atol=1e-12)


def test_a_0_1_fmu_and_a_current_fmu_in_one_process_each_run_their_own_slave(tmp_path):
    """Importers load a slave module once per process by name: the names carry the version.

    Before, both archives held ``model_fmu.py``: after the 0.1 FMU ran, a current FMU in the
    same process ran the 0.1 slave (no FMU state, other variable names).
    """
    from tendonkit.fmu.build import build_model_fmu

    u = _inputs(60)
    with zipfile.ZipFile(LEGACY) as z:
        model = Model.from_json(z.read("resources/model.json").decode())
    current = build_model_fmu(model, tmp_path / "current.fmu", kinematics=False, backend="python")
    _run(LEGACY, u)  # the 0.1 slave module is now loaded in this process
    with zipfile.ZipFile(current) as z:
        names = z.namelist()
    assert any(n.startswith("resources/tendonkit_model_fmu_") for n in names), names
    md, fmu = open_slave(current, "current")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    dt = float(md.defaultExperiment.stepSize)
    vin = [vr[n] for n in model.input_names]
    vout = [vr[n] for n in model.output_names]
    rows = []
    try:
        for k, row in enumerate(u):
            if k == 30:
                saved = fmu.getFMUstate()  # the current slave has state; 0.1's had none
            fmu.setReal(vin, list(row))
            rows.append(fmu.getReal(vout))
            fmu.doStep(k * dt, dt)
        fmu.setFMUstate(saved)
        fmu.setReal(vin, list(u[30]))
        again = fmu.getReal(vout)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    np.testing.assert_allclose(rows, simulate(model, u, initial="model"), rtol=1e-9, atol=1e-12)
    assert again == rows[30]
