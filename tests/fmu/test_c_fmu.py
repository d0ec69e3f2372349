"""The C model FMU (issue 16, points 2-4): equal to ``simulate``, robust, complete, rebuildable.

Every representation, block and term function runs in the compiled C runtime, FMI 2.0 and 3.0,
through fmpy, and must equal ``tendonkit.simulate.simulate`` (the numpy reference) to 1e-10
relative to each output's range — the same random models the compiled kernel is held to
(tests/random_models.py).  Bad calls (non-finite inputs, a wrong step, unknown value
references, a diverging model) must give a logged error status and leave the state as it was.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, instantiate_fmu, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from random_models import KINDS, random_model

import tendonkit as tk
from tendonkit.fmu import cfmu
from tendonkit.fmu.build import export_model_fmu
from tendonkit.schema import Model
from tendonkit.simulate import simulate

pytestmark = pytest.mark.xdist_group("c_fmu")

HOST = [cfmu._host_platform() or "linux64"]
TOL = 1e-10


class Slave:
    """A model FMU of either FMI version in fmpy, initialised at t = 0."""

    def __init__(self, path: Path, logger=None) -> None:
        self.md = read_model_description(str(path))
        self.fmi = int(self.md.fmiVersion[0])
        self.fmu = instantiate_fmu(
            extract(str(path)), self.md, fmi_type="CoSimulation", logger=logger
        )
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.h = float(self.md.defaultExperiment.stepSize)
        if self.fmi == 2:
            self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def set(self, names, values) -> None:
        call = self.fmu.setReal if self.fmi == 2 else self.fmu.setFloat64
        call([self.vr[n] for n in names], [float(v) for v in values])

    def get(self, names) -> list[float]:
        call = self.fmu.getReal if self.fmi == 2 else self.fmu.getFloat64
        return list(call([self.vr[n] for n in names]))

    def step(self, k: int, h: float | None = None) -> None:
        self.fmu.doStep(k * self.h, self.h if h is None else h)

    def run(self, model: Model, u: np.ndarray, start: int = 0) -> tuple[np.ndarray, int | None]:
        """Outputs per sample (set u[k], read, step); the sample whose step failed, or None."""
        rows, failed = [], None
        for k, row in enumerate(u):
            self.set(model.input_names, row)
            rows.append(self.get(model.output_names))
            try:
                self.step(start + k)
            except FMICallException:
                failed = k
                break
        return np.array(rows), failed

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def assert_close(got: np.ndarray, ref: np.ndarray) -> None:
    assert got.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    scale = np.nanmax(np.abs(np.where(np.isfinite(ref), ref, np.nan)), axis=0, initial=0.0)
    err = np.abs(np.where(np.isfinite(ref), got - ref, 0.0))
    assert np.all(err <= TOL * np.maximum(scale, 1e-300)), f"max error {err.max():.3g}"


def export(model: Model, folder: Path, fmi: int = 2, **kw) -> Path:
    path = folder / f"{model.name}_{fmi}.fmu"
    result = export_model_fmu(model, path, kinematics=kw.pop("kinematics", False), fmi=fmi, **kw)
    assert result.backend == "c" and result.fmi == fmi
    return path


def inputs(model: Model, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed + 1)
    return rng.normal(0, 1, (n, len(model.inputs))).cumsum(axis=0) * 0.1


@settings(max_examples=60, derandomize=True, deadline=None, suppress_health_check=list(HealthCheck))
@given(seed=st.integers(0, 2**31), kind=st.sampled_from(KINDS), fmi=st.sampled_from([2, 3]))
def test_the_c_fmu_equals_simulate(tmp_path_factory, seed, kind, fmi):
    """Any model: the FMU's outputs are ``simulate``'s; where it diverges, the step fails."""
    model = random_model(seed, kind, 1.0 if seed % 4 else 3.0)
    u = inputs(model, 150, seed)
    ref = simulate(model, u, initial="model")
    slave = Slave(export(model, tmp_path_factory.mktemp("eq"), fmi, platforms=HOST))
    got, failed = slave.run(model, u)
    slave.close()
    bad = np.isnan(ref).any(axis=1)
    first = int(np.argmax(bad)) if bad.any() else len(ref)
    if failed is None:
        assert not bad.any()
    else:  # the step that diverged is refused, with NaN outputs from there on
        assert bad.any() and failed in (first - 1, first)
    # a growing model multiplies the rounding differences: compare while values are moderate
    large = ~(np.abs(ref[:first]) < 1e6).all(axis=1)
    moderate = int(np.argmax(large)) if large.any() else first
    assert moderate == first or seed % 4 == 0  # the stable draws are compared whole
    assert_close(got[:moderate], ref[:moderate])


def test_a_diverging_model_returns_an_error_and_says_why(tmp_path, capfd):
    for seed in range(100):
        model = random_model(seed, "ss_terms", 30.0)
        u = inputs(model, 300, seed)
        ref = simulate(model, u, initial="model")
        if np.isnan(ref).any() and not np.isnan(ref[0]).any():
            break
    slave = Slave(export(model, tmp_path))
    _, failed = slave.run(model, u)
    assert failed is not None
    out = capfd.readouterr().out
    assert "diverged" in out and "NaN" in out, out
    with pytest.raises(FMICallException):  # and stays refused
        slave.step(failed + 1)
    assert np.isnan(slave.get(model.output_names)).all()
    slave.close()


@pytest.mark.parametrize("fmi", [2, 3])
def test_bad_calls_are_logged_errors_and_change_nothing(tmp_path, capfd, fmi):
    model = random_model(5, "arx_terms", 1.0)
    u = inputs(model, 60, 5)
    ref = simulate(model, u, initial="model")
    slave = Slave(export(model, tmp_path, fmi))
    got, failed = slave.run(model, u[:30])
    assert failed is None
    assert_close(got, ref[:30])
    name = model.input_names[0]
    with pytest.raises(FMICallException):
        slave.set([name], [float("nan")])
    with pytest.raises(FMICallException):
        slave.set([name], [float("inf")])
    slave.set(model.input_names, u[30])
    with pytest.raises(FMICallException):
        slave.step(30, h=slave.h * 2)  # a wrong step size
    with pytest.raises(FMICallException):
        (slave.fmu.getReal if fmi == 2 else slave.fmu.getFloat64)([10_000])
    with pytest.raises(FMICallException):
        slave.set([model.output_names[0]], [1.0])  # outputs cannot be set
    out = capfd.readouterr().out
    assert "must be finite" in out and "refused" in out and "value reference 10000" in out, out
    rest, failed = slave.run(model, u[30:], start=30)  # nothing above changed the state
    assert failed is None
    assert_close(np.vstack([got, rest]), ref)
    slave.close()


@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("kind", ["arx_bilinear", "ss_terms", "sparse_map"])
def test_fmu_state_get_set_serialize_and_reset(tmp_path, fmi, kind):
    model = random_model(11, kind, 1.0)
    u = inputs(model, 80, 11)
    slave = Slave(export(model, tmp_path, fmi))
    slave.run(model, u[:40])
    fmu = slave.fmu
    if fmi == 2:
        state = fmu.getFMUstate()
        blob = fmu.serializeFMUstate(state)
    else:
        state = fmu.getFMUState()
        blob = fmu.serializeFMUState(state)
    first, _ = slave.run(model, u[40:], start=40)
    if fmi == 2:
        fmu.setFMUstate(fmu.deSerializeFMUstate(blob))
    else:
        fmu.setFMUState(fmu.deserializeFMUState(blob))
    again, _ = slave.run(model, u[40:], start=40)
    np.testing.assert_array_equal(again, first)
    # a state whose history index points outside the buffers is refused, not followed
    bad = bytearray(blob)
    bad[48:56] = np.float64(1e6).tobytes()  # [magic, size, t, time index, dead, count, head]
    with pytest.raises(FMICallException):
        if fmi == 2:
            fmu.setFMUstate(fmu.deSerializeFMUstate(bytes(bad)))
        else:
            fmu.setFMUState(fmu.deserializeFMUState(bytes(bad)))
    fmu.reset()
    if fmi == 2:
        fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fresh, _ = slave.run(model, u)
    assert_close(fresh, simulate(model, u, initial="model"))
    slave.close()


@pytest.fixture(scope="module")
def robot_model():
    """An identified SINDYc model of the plant with units and an operating point."""
    from tendonkit.fmu.plant import Plant
    from tendonkit.robot.protocol import pseudo_random

    rec = Plant().record(pseudo_random(30.0, seed=3).u)
    names = ["T1", "T2", "T3", "T4"]
    data = tk.Dataset.from_arrays(
        rec["T_meas"], rec["q"][:, :2], dt=0.03, inputs=names, outputs=["q1", "q2"]
    )
    model = tk.identify(data, "sindyc")
    return tk.schema.Model(
        **{
            **model.__dict__,
            "inputs": tuple(tk.schema.Signal(n, "N") for n in names),
            "outputs": (tk.schema.Signal("q1", "rad"), tk.schema.Signal("q2", "rad")),
        }
    ), rec["T_meas"]


@pytest.mark.parametrize("fmi", [2, 3])
def test_kinematics_start_values_and_description(tmp_path, robot_model, fmi):
    from tendonkit.robot import PAPER_RATIOS
    from tendonkit.robot.kinematics import expand_joints, forward_kinematics

    model, u = robot_model
    path = export(model, tmp_path, fmi, kinematics=True)
    md = read_model_description(str(path))
    variables = {v.name: v for v in md.modelVariables}
    op = model.provenance.details["operating_point"]
    assert all(float(variables[n].start) == pytest.approx(op[n]) for n in model.input_names)
    assert variables["T1"].unit == "N" and variables["q3"].unit == "rad"
    assert variables["ee_x"].unit == "m" and variables["ratio_3"].causality == "parameter"
    assert md.modelName == model.name and "sindyc" in md.description
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    assert md.defaultExperiment.stepSize == "0.03"
    slave = Slave(path)
    assert slave.get(model.input_names) == pytest.approx([op[n] for n in model.input_names])
    outs = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]
    rows = []
    for k, row in enumerate(u[:200]):
        slave.set(model.input_names, row)
        rows.append(slave.get(outs))
        slave.step(k)
    slave.close()
    y = simulate(model, u[:200], initial="model")
    q = expand_joints(y, PAPER_RATIOS)
    expected = np.hstack([y, q[:, 2:], forward_kinematics(q)])
    assert np.ptp(expected[:, 0]) > 0.01
    assert_close(np.array(rows), expected)


@pytest.mark.parametrize("fmi", [2, 3])
def test_fmpy_validation_and_fmutool_check(tmp_path, robot_model, fmi):
    model, _ = robot_model
    path = export(model, tmp_path, fmi, kinematics=True)
    assert validate_fmu(str(path)) == []
    fmutool = Path(sys.executable).with_name("fmutool")
    r = subprocess.run(
        [str(fmutool), "-input", str(path), "-check"], capture_output=True, text=True, timeout=120
    )
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    assert (
        f"compliant with FMI-{fmi}.0" in out and f"No semantic error against the FMI-{fmi}" in out
    )


@pytest.mark.parametrize("fmi", [2, 3])
def test_the_archive_carries_sources_and_three_platforms_without_python(tmp_path, robot_model, fmi):
    model, _ = robot_model
    path = tmp_path / "m.fmu"
    result = export_model_fmu(model, path, fmi=fmi)
    assert set(result.platforms) == {"linux64", "win64", "darwin64"}, result.notes
    assert "linux64, win64, darwin64" in result.summary()
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        ident = cfmu.model_identifier(model.name)
        for plat, (tuple_, _, suffix) in cfmu.PLATFORMS.items():
            binary = f"binaries/{plat if fmi == 2 else tuple_}/{ident}{suffix}"
            assert binary in names
            data = zf.read(binary)
            assert b"python" not in data.lower()  # links no libpython, imports nothing of it
        assert b"msvcrt.dll" in zf.read(
            f"binaries/{'win64' if fmi == 2 else 'x86_64-windows'}/{ident}.dll"
        )
        for source in (*cfmu.SOURCES, *cfmu.HEADERS, *cfmu.FMI_HEADERS):
            assert f"sources/{source}" in names
        assert ("sources/buildDescription.xml" in names) == (fmi == 3)
        assert f"resources/{cfmu.RESOURCE}" in names
    assert path.stat().st_size < 200_000


@pytest.mark.parametrize("fmi", [2, 3])
def test_an_importer_can_rebuild_the_binary_from_the_sources(tmp_path, fmi):
    """fmpy's CMake build of ``sources/`` (what any importer can do) gives the same outputs."""
    from fmpy.build import build_platform_binary

    if shutil.which("cmake") is None:
        pytest.fail("cmake is needed to rebuild an FMU from its sources (apt install cmake)")
    model = random_model(21, "sparse_map", 1.0)
    path = export(model, tmp_path, fmi, platforms=HOST)
    folder = tmp_path / "unzipped"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(folder)
    shutil.rmtree(folder / "binaries")
    (tmp_path / "build").mkdir()
    build_platform_binary(folder, tmp_path / "build")
    assert list((folder / "binaries").rglob("*.so"))
    md = read_model_description(str(folder))
    fmu = instantiate_fmu(str(folder), md, fmi_type="CoSimulation")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    if fmi == 2:
        fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    u = inputs(model, 100, 21)
    rows = []
    get, set_ = (fmu.getReal, fmu.setReal) if fmi == 2 else (fmu.getFloat64, fmu.setFloat64)
    for k, row in enumerate(u):
        set_([vr[n] for n in model.input_names], list(row))
        rows.append(get([vr[n] for n in model.output_names]))
        fmu.doStep(k * model.dt, model.dt)
    fmu.terminate()
    fmu.freeInstance()
    assert_close(np.array(rows), simulate(model, u, initial="model"))


@pytest.mark.parametrize("damage", ["truncated", "foreign"])
def test_a_damaged_model_resource_is_refused_at_instantiation(tmp_path, capfd, damage):
    path = export(random_model(3, "sparse_map", 1.0), tmp_path, platforms=HOST)
    folder = Path(extract(str(path)))
    resource = folder / "resources" / cfmu.RESOURCE
    data = resource.read_bytes()
    if damage == "truncated":
        resource.write_bytes(data[: len(data) // 16 * 8])  # whole numbers, half of them
    else:  # a plausible header with counts far beyond the file
        values = np.frombuffer(data, dtype="<f8").copy()
        values[3] = 90_000.0  # number of inputs
        resource.write_bytes(values.tobytes())
    md = read_model_description(str(folder))
    with pytest.raises(Exception, match="instantiate"):
        instantiate_fmu(str(folder), md, fmi_type="CoSimulation")
    assert "corrupt" in capfd.readouterr().out


def test_export_falls_back_to_python_and_says_why(tmp_path, monkeypatch):
    monkeypatch.setenv("TENDONKIT_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(cfmu, "_zig", lambda: None)
    monkeypatch.setattr(cfmu, "_system_cc", lambda: None)
    model = random_model(2, "arx_linear", 1.0)
    result = export_model_fmu(model, tmp_path / "m.fmu", kinematics=False)
    assert result.backend == "python"
    assert any("fell back to the Python backend" in n for n in result.notes), result.notes
    assert any("no C compiler" in n for n in result.notes), result.notes
    with pytest.raises(tk.errors.FMUError, match="No binary of the C runtime"):
        export_model_fmu(model, tmp_path / "c.fmu", kinematics=False, backend="c")
    with pytest.raises(tk.errors.OptionError, match=r"FMI 2\.0 only"):
        export_model_fmu(model, tmp_path / "p.fmu", kinematics=False, backend="python", fmi=3)


def test_cli_export_reports_backend_and_platforms(tmp_path, robot_model, capsys):
    from tendonkit.cli import main

    model, _ = robot_model
    src = tmp_path / "m.json"
    src.write_text(model.to_json())
    out = tmp_path / "m.fmu"
    assert main(["export", str(src), "-o", str(out), "--fmi", "3"]) == 0
    stdout = capsys.readouterr().out
    assert "FMI 3.0 co-simulation, C, no Python needed" in stdout
    assert "linux64, win64, darwin64" in stdout
    assert read_model_description(str(out)).fmiVersion == "3.0"
    assert main(["export", str(src), "-o", str(tmp_path / "p.fmu"), "--backend", "python",
                 "--fmi", "3"]) == 2  # fmt: skip


_AFTER_A_SESSION = r"""
import gc, sys
from fmpy import extract, instantiate_fmu, read_model_description
from tendonkit.fmu.build import cached_plant_fmu
from tendonkit.robot.collect import PlantSession
session = PlantSession(cached_plant_fmu())
session.close()
del session
gc.collect()
md = read_model_description(sys.argv[1])
fmu = instantiate_fmu(extract(sys.argv[1]), md, fmi_type="CoSimulation")
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
try:
    fmu.doStep(0.0, 123.0)  # refused: the FMU logs an error through fmpy's logger proxy
except Exception as exc:
    print("REFUSED", exc)
print("ALIVE")
"""


def test_an_fmu_that_logs_after_a_closed_plant_session_does_not_crash(tmp_path):
    """fmpy's logger proxy keeps the last logger registered; a plant session's must outlive it.

    Before, ``PlantSession`` registered a logger of its own, freed with the session, and the
    next FMU of the process that logged (a C model FMU refusing a step) crashed the process.
    """
    path = export(random_model(5, "arx_terms", 1.0), tmp_path, platforms=HOST)
    r = subprocess.run(
        [sys.executable, "-c", _AFTER_A_SESSION, str(path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and "ALIVE" in r.stdout, (r.returncode, r.stdout, r.stderr[-2000:])
    assert "REFUSED" in r.stdout and "communication step 123" in r.stdout


def _edge_models() -> dict[str, Model]:
    from tendonkit.schema import ARX, Block, Signal, StateSpace
    from tendonkit.terms import Factor, Term

    one = np.array([[1.0]])

    def loop(k: int) -> Factor:
        return Factor("u", "slew_lag", lag=k, param=0.3, param2=0.05, minus="y", weight=0.4)

    return {
        # no state at all: a static gain
        "static": Model(
            "static gain",
            0.1,
            (Signal("u"),),
            (Signal("y"),),
            StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), 2 * one),
        ),
        # an input named like FMI 3.0's independent variable, a long fractional delay,
        # a name that is no C identifier
        "time": Model(
            "m-1",
            0.1,
            (Signal("time"),),
            (Signal("y", "m"),),
            StateSpace(0.5 * one, one, one, 0 * one),
            input_blocks=(Block("delay", "time", {"samples": 40.5}),),
        ),
        # a pure FIR ARX with a different delay per input
        "fir": Model(
            "fir",
            0.1,
            (Signal("u1"), Signal("u2")),
            (Signal("y1"), Signal("y2")),
            ARX((), (np.ones((2, 2)), 0.5 * np.ones((2, 2))), (0, 3)),
        ),
        # an operating point (pem's offsets): an integrator driven by u - u0, a level y0
        "offsets": Model(
            "offsets",
            0.1,
            (Signal("u"),),
            (Signal("y1"), Signal("y2")),
            StateSpace(
                np.array([[0.8, 0.0], [0.1, 1.0]]),
                np.array([[1.0], [0.0]]),
                np.array([[0.0, 1.0], [1.0, 0.0]]),
                np.array([[0.0], [0.5]]),
                x0=np.array([0.3, -1.0]),
                u0=np.array([0.25]),
                y0=np.array([0.0, 4.0]),
            ),
        ),
        # an actuator in a loop with its load: a rate-limited lag of u - 0.4·y at two lags
        "loop": Model(
            "loop",
            0.1,
            (Signal("u"),),
            (Signal("y"),),
            ARX(
                (np.array([[-0.8]]),),
                (np.zeros((1, 1)),),
                (1,),
                terms=tuple(Term((loop(k),)) for k in (1, 2)),
                term_coefficients=np.array([[0.3], [0.2]]),
            ),
        ),
    }


@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("case", ["static", "time", "fir", "offsets", "loop"])
def test_edge_models_export_validate_and_equal_simulate(tmp_path, case, fmi):
    model = _edge_models()[case]
    path = export(model, tmp_path, fmi, platforms=HOST)
    assert validate_fmu(str(path)) == []
    u = np.random.default_rng(0).normal(size=(100, len(model.inputs)))
    slave = Slave(path)
    got, failed = slave.run(model, u)
    slave.close()
    assert failed is None
    assert_close(got, simulate(model, u, initial="model"))
