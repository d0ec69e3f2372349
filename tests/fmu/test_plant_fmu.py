"""The plant FMU: a valid FMI 2.0 co-simulation FMU that reproduces :class:`Plant` exactly.

Tolerances: the FMU wraps the same ``Plant`` code, so the outputs agree to rounding.  1e-12 (in
rad, m and N) allows for the two code paths that differ only in the order of floating-point
operations (the end-effector kinematics is vectorised in ``Plant.run`` and scalar per step);
the observed difference is ~1e-16.
"""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import fmpy  # a dependency: missing, the module fails (never skips)
import numpy as np
import pytest

from tendonkit.fmu.build import build_plant_fmu
from tendonkit.fmu.plant import Plant, PlantConfig
from tendonkit.fmu.plant_fmu import INPUTS, OUTPUTS, STEP, read_parameters
from tendonkit.robot.protocol import pseudo_random

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_plant_fmu")

TOL = 1e-12
KEYS = ("q", "ee", "T_meas", "q_true", "ee_true")
EFFECTS = PlantConfig(
    friction_on=True,
    delay_on=True,
    delay_s=0.05,
    noise_on=True,
    camera_on=True,
    backlash_on=True,
    mount="horiz_tilt",
    seed=7,
)


@pytest.fixture(scope="session")
def fmus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plant_fmu")
    nominal = build_plant_fmu(folder / "nominal.fmu")
    effects = build_plant_fmu(folder / "effects.fmu", EFFECTS)
    return {"nominal": nominal, "effects": effects}


@pytest.fixture(scope="session")
def commands():
    """20 s of the pseudo-random protocol: fast, and it exercises every tendon."""
    return pseudo_random(20.0, seed=2).u


def expected(config: PlantConfig, u: np.ndarray) -> np.ndarray:
    """``Plant.run`` outputs in the FMU's output order."""
    out = Plant(config).run(u)
    return np.hstack([out[k] for k in KEYS])


class Slave:
    """A bare fmpy instance with a log collector (independent of tendonkit.robot.collect)."""

    def __init__(self, path, start: dict | None = None) -> None:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )

        md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.log: list[tuple[int, str]] = []
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(
            lambda env, name, status, cat, msg: self.log.append((status, msg.decode()))
        )
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        self._cb = cb
        self.fmu = FMU2Slave(
            guid=md.guid,
            unzipDirectory=extract(str(path)),
            modelIdentifier=md.coSimulation.modelIdentifier,
            instanceName="test",
        )
        self.fmu.instantiate(callbacks=cb, loggingOn=True)
        for name, value in (start or {}).items():
            setter = {float: self.fmu.setReal, bool: self.fmu.setBoolean, str: self.fmu.setString}
            setter[type(value)]([self.vr[name]], [value])
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.vin = [self.vr[n] for n in INPUTS]
        self.vout = [self.vr[n] for n in OUTPUTS]

    def run(self, u: np.ndarray) -> np.ndarray:
        rows = []
        for k, row in enumerate(u):
            self.fmu.setReal(self.vin, list(row))
            self.fmu.doStep(k * STEP, STEP)
            rows.append(self.fmu.getReal(self.vout))
        return np.array(rows)

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


# --------------------------------------------------------------------------- model description
@pytest.mark.parametrize("which", ["nominal", "effects"])
def test_validates_with_zero_problems(fmus, which):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(fmus[which])) == []
    # The FMU Manipulation Toolbox checks the XSD and the FMI semantics independently.
    exe = Path(sys.executable).with_name("fmutool")
    report = subprocess.run(
        [str(exe), "-input", str(fmus[which]), "-check"], capture_output=True, text=True
    )
    text = report.stdout + report.stderr
    assert "ERROR" not in text and "No semantic error" in text, text
    assert "seems to be compliant with FMI-2.0" in text


def _description(path) -> ET.Element:
    with zipfile.ZipFile(path) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def test_interface_units_structure_and_step(fmus):
    root = _description(fmus["effects"])
    cosim = root.find("CoSimulation")
    assert cosim.get("canHandleVariableCommunicationStepSize") == "false"
    assert float(root.find("DefaultExperiment").get("stepSize")) == STEP
    variables = {sv.get("name"): sv for sv in root.iter("ScalarVariable")}
    units = {n: sv[0].get("unit") for n, sv in variables.items()}
    assert [units[n] for n in INPUTS] == ["N"] * 4
    assert {units[f"q{i}"] for i in range(1, 7)} == {"rad"}
    assert units["ee_x"] == units["ee_z_true"] == "m" and units["T4"] == "N"
    assert units["forcelag_kt"] == "N/m" and units["camera_fc"] == "Hz"
    defined = {u.get("name") for u in root.iter("Unit")}
    assert {u for u in units.values() if u} <= defined
    # No direct feedthrough: every output has an explicitly empty dependency list.
    outs = root.find("ModelStructure/Outputs")
    names = list(variables)
    assert sorted(names[int(u.get("index")) - 1] for u in outs) == sorted(OUTPUTS)
    assert all(u.get("dependencies") == "" for u in outs)
    assert len(root.find("ModelStructure/InitialUnknowns")) == len(OUTPUTS)
    # The built configuration is the parameters' start values.
    start = {n: sv[0].get("start") for n, sv in variables.items()}
    assert start["friction_on"] == "true" and start["mount"] == "horiz_tilt"
    assert float(start["delay_s"]) == 0.05 and start["seed"] == "7"
    assert variables["mount"][0].tag == "String"


# --------------------------------------------------------------------------- behaviour
@pytest.mark.parametrize(
    ("which", "config"), [("nominal", PlantConfig()), ("effects", EFFECTS)], ids=["nominal", "fx"]
)
def test_outputs_equal_plant_run(fmus, commands, which, config):
    slave = Slave(fmus[which])
    try:
        got = slave.run(commands)
    finally:
        slave.close()
    want = expected(config, commands)
    assert got.shape == want.shape == (len(commands), len(OUTPUTS))
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


def test_simulate_fmu_equals_manual_loop(fmus, commands):
    from fmpy import simulate_fmu

    n = len(commands)
    t = np.arange(n) * STEP
    signals = np.zeros(n, dtype=[("time", float)] + [(name, float) for name in INPUTS])
    signals["time"] = t
    for k, name in enumerate(INPUTS):
        signals[name] = commands[:, k]
    res = simulate_fmu(
        str(fmus["effects"]),
        start_time=0.0,
        stop_time=n * STEP,
        output_interval=STEP,
        input=signals,
        output=list(OUTPUTS),
    )
    via_simulate = np.column_stack([res[name] for name in OUTPUTS])
    slave = Slave(fmus["effects"])
    try:
        manual = slave.run(commands)
    finally:
        slave.close()
    # Row 0 of simulate_fmu is the initial state; rows 1.. follow the steps.
    assert via_simulate.shape == (n + 1, len(OUTPUTS))
    np.testing.assert_array_equal(via_simulate[1:], manual)


def test_parameters_are_applied_at_initialisation(fmus, commands):
    start = {"friction_on": True, "forcelag_on": True, "mount": "down", "delay_s": 0.03}
    slave = Slave(fmus["nominal"], start)
    try:
        got = slave.run(commands[:200])
    finally:
        slave.close()
    config = PlantConfig(friction_on=True, forcelag_on=True, mount="down", delay_s=0.03)
    np.testing.assert_allclose(got, expected(config, commands[:200]), rtol=0, atol=TOL)


def test_other_step_sizes_are_refused_without_moving(fmus, commands):
    from fmpy.fmi1 import FMICallException

    slave = Slave(fmus["nominal"])
    try:
        with pytest.raises(FMICallException, match="discard"):
            slave.fmu.doStep(0.0, 0.01)
        errors = [m for s, m in slave.log if s == 3]
        assert errors and "0.01" in errors[-1] and "0.03" in errors[-1]
        # The refused step changed nothing: the next 30 ms steps match the plant exactly.
        got = slave.run(commands[:10])
    finally:
        slave.close()
    np.testing.assert_allclose(got, expected(PlantConfig(), commands[:10]), rtol=0, atol=TOL)


def test_bad_parameters_give_one_clear_error_and_no_crash(fmus):
    from fmpy.fmi1 import FMICallException

    bad = {"friction_mu_s": 0.9, "delay_s": 3.0, "mount": "sideways"}
    slave = Slave(fmus["nominal"], bad)
    try:
        errors = [m for s, m in slave.log if s == 3]
        assert len(errors) == 1
        for text in ("friction_mu_s", "delay_s must be in [0, 0.15]", "mount must be one of"):
            assert text in errors[0]
        with pytest.raises(FMICallException, match="discard"):
            slave.fmu.doStep(0.0, STEP)
        assert np.isnan(slave.fmu.getReal(slave.vout)).all()
    finally:
        slave.close()  # must not abort the process (pythonfmu double-free after exceptions)


def test_parameter_file_is_data_never_code(tmp_path):
    # The resource file is parsed as JSON; a string that looks like code stays a string and
    # is refused by the configuration's checks, unknown names are ignored.
    pwned = tmp_path / "pwned"  # an absolute path: the check sees it wherever the process runs
    code = f"__import__('pathlib').Path({str(pwned)!r}).touch()"
    (tmp_path / "plant_parameters.json").write_text(
        json.dumps({"delay_s": code, "not_a_parameter": 1, "friction_on": True})
    )
    params = read_parameters(str(tmp_path))
    assert params["delay_s"] == code and params["friction_on"] is True
    assert "not_a_parameter" not in params
    assert not pwned.exists()


def test_every_plant_variable_is_described(fmus):
    """Importers show the description beside each variable (issue 16: 49 of 75 had none)."""
    from fmpy import read_model_description

    md = read_model_description(str(fmus["nominal"]))
    bare = [v.name for v in md.modelVariables if not (v.description or "").strip()]
    assert len(md.modelVariables) >= 75 and bare == []
    about = {v.name: v.description for v in md.modelVariables}
    assert "capstan" in about["friction_mu_k"] and "m/s²" in about["gravity"]
    assert about["ratio_5"].startswith("joint-angle ratio q5/q1")
