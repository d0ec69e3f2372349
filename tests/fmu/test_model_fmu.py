"""Model export: every representation becomes a valid FMU whose outputs equal ``simulate``.

Reference: ``simulate(model, u, initial="model")``, the constant-ratio reconstruction
(``expand_joints``) and the forward kinematics.  Tolerance 1e-9 (rad, m): the FMU evaluates the
model sample by sample (``Stepper``, itself equal to ``simulate`` to ~1e-13 on these models) and
the kinematics per sample instead of vectorised; 1e-9 leaves room for the rounding of identified
models whose states are of order 1e2 and still catches any wrong sample alignment (~1e-3).
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmi_slave import open_slave

import tendonkit as tk
from tendonkit.cli import main
from tendonkit.errors import OptionError
from tendonkit.fmu import build as _build
from tendonkit.fmu.build import build_model_fmu
from tendonkit.fmu.plant import Plant
from tendonkit.robot.kinematics import expand_joints, forward_kinematics
from tendonkit.robot.protocol import pseudo_random
from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.simulate import simulate
from tendonkit.terms import Factor, Term

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_model_fmu")

TOL = 1e-9
INPUTS = ["T1", "T2", "T3", "T4"]
JOINT_OUTPUTS = ["q1", "q2", "q3", "q4", "q5", "q6", "ee_x", "ee_y", "ee_z"]


def plant_data(seed: int, seconds: float) -> tk.Dataset:
    """Measured forces -> measured base joints of the nominal plant (the paper's setting)."""
    rec = Plant().record(pseudo_random(seconds, seed=seed).u)
    return tk.Dataset.from_arrays(
        rec["T_meas"], rec["q"][:, :2], dt=0.03, inputs=INPUTS, outputs=["q1", "q2"]
    )


@pytest.fixture(autouse=True, params=["c", "python"])
def backend(request, monkeypatch):
    """Every test here runs against both backends (compiled C and pythonfmu)."""
    export = functools.partial(_build.build_model_fmu, backend=request.param)
    monkeypatch.setitem(globals(), "build_model_fmu", export)
    return request.param


@pytest.fixture(scope="session")
def identified():
    train = plant_data(1, 90.0)
    return {
        "n4sid": tk.identify(train, "n4sid", order=8),
        "arx": tk.identify(train, "arx", na=4, nb=4, nk=0),
        "arx_bilinear": tk.identify(train, "arx", na=3, nb=3, nk=1, bilinear=True),
        "sindyc": tk.identify(train, "sindyc"),
    }


@pytest.fixture(scope="session")
def validation():
    return plant_data(2, 15.0).experiments[0].u


def reference(model: Model, u: np.ndarray, ratios=None) -> np.ndarray:
    y = simulate(model, u, initial="model")
    iq = [model.output_names.index("q1"), model.output_names.index("q2")]
    q = expand_joints(y[:, iq], ratios if ratios is not None else tk.robot.PAPER_RATIOS)
    return np.hstack([y, q[:, 2:], forward_kinematics(q)])


def run_fmu(path: Path, u: np.ndarray, inputs, outputs, start=None, changes=None) -> np.ndarray:
    """fmpy, FMI co-simulation order at each point: set inputs, read outputs, doStep."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    dt = float(md.defaultExperiment.stepSize)
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=extract(str(path)),
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName="model",
    )
    fmu.instantiate()
    for name, value in (start or {}).items():
        fmu.setReal([vr[name]], [value])
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    vin, vout = [vr[n] for n in inputs], [vr[n] for n in outputs]
    rows = []
    try:
        for k, row in enumerate(u):
            for name, value in (changes or {}).get(k, {}).items():
                fmu.setReal([vr[name]], [value])
            fmu.setReal(vin, list(row))
            rows.append(fmu.getReal(vout))
            fmu.doStep(k * dt, dt)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    return np.array(rows)


def fmutool_check(path: Path) -> str:
    exe = Path(sys.executable).with_name("fmutool")
    r = subprocess.run(
        [str(exe), "-input", str(path), "-check"], capture_output=True, text=True, timeout=120
    )
    return r.stdout + r.stderr


def assert_valid(path: Path) -> None:
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(path)) == []
    report = fmutool_check(path)
    assert "ERROR" not in report, report
    assert "seems to be compliant with FMI-2.0" in report
    assert "No semantic error" in report


@pytest.mark.parametrize("method", ["n4sid", "arx", "arx_bilinear", "sindyc"])
def test_identified_models_export_validate_and_match_simulate(
    tmp_path, identified, validation, method
):
    model = identified[method]
    path = build_model_fmu(model, tmp_path / f"{method}.fmu")
    assert_valid(path)
    got = run_fmu(path, validation, INPUTS, JOINT_OUTPUTS)
    want = reference(model, validation)
    assert np.ptp(want[:, 0]) > 0.05  # the validation record really moves the joints
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


def _root(path: Path) -> ET.Element:
    with zipfile.ZipFile(path) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def _dependencies(path: Path) -> dict[str, str]:
    root = _root(path)
    names = [sv.get("name") for sv in root.iter("ScalarVariable")]
    deps = {}
    for u in root.find("ModelStructure/Outputs"):
        deps[names[int(u.get("index")) - 1]] = " ".join(
            names[int(i) - 1] for i in u.get("dependencies").split()
        )
    return deps


def test_feedthrough_is_declared_only_where_it_exists(tmp_path, identified):
    arx = build_model_fmu(identified["arx"], tmp_path / "arx.fmu")  # nk = 0: direct
    n4sid = build_model_fmu(identified["n4sid"], tmp_path / "n4sid.fmu")  # D = 0
    assert _dependencies(arx)["q1"] == "T1 T2 T3 T4"
    assert _dependencies(arx)["ee_y"] == "T1 T2 T3 T4"
    assert set(_dependencies(n4sid).values()) == {""}
    root = _root(arx)
    assert float(root.find("DefaultExperiment").get("stepSize")) == 0.03
    assert root.find("CoSimulation").get("canHandleVariableCommunicationStepSize") == "false"
    units = {sv.get("name"): sv[0].get("unit") for sv in root.iter("ScalarVariable")}
    assert units["T1"] is None  # the identified model's signals carry no unit
    assert units["q4"] == "rad" and units["ee_z"] == "m"


def _synthetic(kind: str) -> Model:
    """Models no identifier made: every representation with terms, offsets and all blocks."""
    rng = np.random.default_rng(5)
    ins = tuple(Signal(n, "N") for n in INPUTS)
    outs = (Signal("q1", "rad"), Signal("q2", "rad"))
    blocks_in = (
        Block("delay", "T1", {"samples": 2.0}),
        Block("dead_zone", "T2", {"threshold": 2.0, "center": 105.0}),
        Block("play", "T3", {"width": 1.0}),
        Block("first_order_lag", "T4", {"pole": 0.6}),
        Block("rate_limit", "T1", {"rate": 5.0}),
        Block("saturation", "T3", {"lower": 40.0, "upper": 170.0}),
        Block("second_order_section", "T4", {"b1": -0.5, "b2": 0.3, "a1": -1.2, "a2": 0.5}),
    )
    blocks_out = (
        Block("play", "q1", {"width": 0.002}),
        Block("first_order_lag", "q2", {"pole": 0.3}),
    )
    if kind == "state_space":
        a = rng.normal(size=(3, 3))
        rep = StateSpace(
            0.9 * a / np.max(np.abs(np.linalg.eigvals(a))),
            1e-3 * rng.normal(size=(3, 4)),
            rng.normal(size=(2, 3)),
            1e-4 * rng.normal(size=(2, 4)),
            x0=0.01 * rng.normal(size=3),
            terms=(Term((Factor("q1", fn="sin"),)), Term((Factor("T2", diff=1),))),
            E=1e-3 * rng.normal(size=(3, 2)),
        )
        return Model(kind, 0.03, ins, outs, rep, input_blocks=blocks_in, output_blocks=blocks_out)
    if kind == "arx":
        rep = ARX(
            A=(np.array([[-0.8, 0.0], [0.0, -0.7]]),),
            B=(1e-3 * rng.normal(size=(2, 4)),),
            nk=(0, 1, 0, 2),
            offset=np.array([-0.01, 0.02]),
            terms=(Term((Factor("q1", fn="tanh", lag=1),)), Term((Factor("T1", scale=0.01),))),
            term_coefficients=1e-3 * rng.normal(size=(2, 2)),
        )
        return Model(kind, 0.03, ins, outs, rep, input_blocks=blocks_in, output_blocks=blocks_out)
    terms = (
        Term(),
        Term((Factor("s1"),)),
        Term((Factor("s2", lag=1),)),
        Term((Factor("T1", offset=105.0, scale=0.01),)),
        Term((Factor("T2", offset=105.0, scale=0.01, lag=2), Factor("s1", fn="cos"))),
    )
    coef = np.array([[0.0, 0.0], [0.9, 0.05], [0.0, 0.85], [0.01, 0.0], [0.0, 0.01]])
    rep = SparseMap(terms, coef, output_states=(0, 1), x0=np.array([0.01, -0.02]))
    states = (Signal("s1", "rad"), Signal("s2", "rad"))
    return Model(kind, 0.05, ins, outs, rep, states=states, input_blocks=blocks_in)


@pytest.mark.parametrize("kind", ["state_space", "arx", "sparse_map"])
def test_every_representation_with_terms_and_blocks_exports(tmp_path, validation, kind):
    model = _synthetic(kind)
    path = build_model_fmu(model, tmp_path / f"{kind}.fmu", ratios=(0.6, 0.62, 0.2, 0.25))
    assert_valid(path)
    units = {sv.get("name"): sv[0].get("unit") for sv in _root(path).iter("ScalarVariable")}
    assert units["T1"] == "N" and units["q1"] == "rad"
    got = run_fmu(path, validation, INPUTS, JOINT_OUTPUTS)
    want = reference(model, validation, ratios=(0.6, 0.62, 0.2, 0.25))
    assert np.all(np.isfinite(want))
    np.testing.assert_allclose(got, want, rtol=0, atol=TOL)


def test_ratios_are_tunable_during_the_run(tmp_path, identified, validation):
    model = identified["n4sid"]
    path = build_model_fmu(model, tmp_path / "m.fmu")
    u = validation[:100]
    got = run_fmu(path, u, INPUTS, ["q1", "q3", "q6"], changes={50: {"ratio_3": 0.5}})
    np.testing.assert_allclose(got[:50, 1], 0.6493 * got[:50, 0], rtol=1e-12)
    np.testing.assert_allclose(got[50:, 1], 0.5 * got[50:, 0], rtol=1e-12)
    np.testing.assert_allclose(got[:, 2], 0.2291 * reference(model, u)[:, 1], atol=TOL)


def test_no_kinematics_exports_any_output_names_and_other_steps_are_refused(tmp_path):
    from fmpy import read_model_description
    from fmpy.fmi1 import FMICallException

    model = tk.testsystems.random_state_space(3, 2, 2, seed=1, dt=0.1)
    with pytest.raises(OptionError, match="outputs named q1 and q2"):
        build_model_fmu(model, tmp_path / "k.fmu")
    path = build_model_fmu(model, tmp_path / "plain.fmu", kinematics=False)
    assert_valid(path)
    md = read_model_description(str(path))
    assert [v.name for v in md.modelVariables if v.causality == "output"] == ["y1", "y2"]
    u = np.random.default_rng(0).normal(size=(30, 2))
    got = run_fmu(path, u, model.input_names, model.output_names)
    np.testing.assert_allclose(got, simulate(model, u, initial="model"), rtol=0, atol=TOL)
    _, fmu = open_slave(path, "x")
    with pytest.raises(FMICallException, match=r"discard|error"):  # python: discard; c: error
        fmu.doStep(0.0, 0.03)
    fmu.doStep(0.0, 0.1)  # the model's own step still works
    fmu.terminate()
    fmu.freeInstance()


def test_export_cli_with_ratios_file_and_clear_errors(tmp_path, identified, capsys):
    model_file = tmp_path / "m.json"
    identified["arx"].save(model_file)
    ratios = tmp_path / "ratios.json"
    ratios.write_text(json.dumps({"q3": 0.6, "q4": 0.61, "q5": 0.2, "q6": 0.3}))
    out = tmp_path / "m.fmu"
    assert main(["export", str(model_file), "-o", str(out), "--ratios", str(ratios)]) == 0
    assert "exported" in capsys.readouterr().out
    start = {sv.get("name"): sv[0].get("start") for sv in _root(out).iter("ScalarVariable")}
    assert float(start["ratio_4"]) == 0.61 and float(start["ratio_6"]) == 0.3
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"q3": 2.0, "q9": 1, "q5": "x"}))
    plain = tmp_path / "plain.json"
    tk.testsystems.random_state_space(2, 1, 1, seed=0).save(plain)
    assert main(["export", str(plain), "-o", str(tmp_path / "p.txt"), "--ratios", str(bad)]) == 2
    err = capsys.readouterr().err
    for text in (
        "must end in .fmu",
        "unknown keys ['q9']",
        "q5: expected a finite number",
        "q4: expected a finite number",
        "needs model outputs named q1 and q2",
    ):
        assert text in err
    assert main(["export", str(tmp_path / "missing.json"), "-o", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err


# -- issue 16, point 3: state, names, step size --------------------------------------------------


@pytest.mark.parametrize("method", ["n4sid", "arx_bilinear", "sindyc"])
def test_fmu_state_get_set_and_serialise(tmp_path, identified, validation, method):
    """Importers that iterate (step, look, go back) get exactly the same run again."""
    path = build_model_fmu(identified[method], tmp_path / f"{method}.fmu")
    md, fmu = open_slave(path)
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    vr = {v.name: v.valueReference for v in md.modelVariables}
    vin, vout = [vr[n] for n in INPUTS], [vr[n] for n in JOINT_OUTPUTS]
    dt = float(md.defaultExperiment.stepSize)

    def steps(start: int, stop: int) -> np.ndarray:
        rows = []
        for k in range(start, stop):
            fmu.setReal(vin, list(validation[k]))
            rows.append(fmu.getReal(vout))
            fmu.doStep(k * dt, dt)
        return np.array(rows)

    try:
        steps(0, 40)
        saved = fmu.getFMUstate()
        blob = fmu.serializeFMUstate(saved)
        first = steps(40, 80)
        fmu.setFMUstate(saved)
        again = steps(40, 80)
        np.testing.assert_array_equal(again, first)
        fmu.setFMUstate(fmu.deSerializeFMUstate(blob))
        np.testing.assert_array_equal(steps(40, 80), first)
        fmu.freeFMUstate(saved)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    expected = reference(identified[method], validation[:80])
    np.testing.assert_allclose(first, expected[40:80], atol=TOL)


def test_each_fmu_says_which_model_it_is(tmp_path, identified):
    from fmpy import read_model_description

    model = identified["arx"]
    path = build_model_fmu(model, tmp_path / "m.fmu")
    md = read_model_description(str(path))
    assert md.modelName == model.name
    assert "arx" in md.description and "exported by tendonkit" in md.description
    assert tk.__version__ in md.description


def test_csv_timestamp_noise_does_not_reach_the_step_size(tmp_path, capsys):
    """Timestamps k·0.03 written as decimals differ from 0.03 by ~1e-15: the step is 0.03."""
    n = 600
    rng = np.random.default_rng(3)
    t = 1000.0 + np.arange(n) * 0.03  # a rig clock: large times, coarse rounding
    u = rng.normal(100, 5, (n, 2))
    y = np.cumsum(u - 100, axis=0)[:, :1] * 1e-3
    rows = zip(t.tolist(), u[:, 0].tolist(), u[:, 1].tolist(), y[:, 0].tolist(), strict=True)
    text = "t,T1,T2,q1\n" + "".join(f"{a!r},{b!r},{c!r},{d!r}\n" for a, b, c, d in rows)
    assert float(np.median(np.diff(t))) != 0.03  # the decimals carry the noise
    data = tmp_path / "d.csv"
    data.write_text(text)
    assert tk.Dataset.from_csv(data, ["T1", "T2"], ["q1"]).dt == 0.03
    model = tmp_path / "m.json"
    assert main([
        "identify", str(data), "--inputs", "T1,T2", "--outputs", "q1", "-o", str(model)
    ]) == 0  # fmt: skip
    assert main(["export", str(model), "-o", str(tmp_path / "m.fmu"), "--no-kinematics"]) == 0
    with zipfile.ZipFile(tmp_path / "m.fmu") as zf:
        root = ET.fromstring(zf.read("modelDescription.xml"))
    assert root.find("DefaultExperiment").get("stepSize") == "0.03"


def test_inputs_start_at_the_operating_point(tmp_path, identified):
    """A master that never sets the inputs meets the model where it was identified, not at 0 N."""
    model = identified["arx"]
    op = model.provenance.details["operating_point"]
    assert list(op) == INPUTS and all(60.0 < v < 150.0 for v in op.values()), op
    path = build_model_fmu(model, tmp_path / "m.fmu")
    md, fmu = open_slave(path)
    starts = {v.name: float(v.start) for v in md.modelVariables if v.causality == "input"}
    assert starts == pytest.approx(op)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    dt = float(md.defaultExperiment.stepSize)
    try:
        rows = []
        for k in range(200):  # inputs never set
            rows.append(fmu.getReal([vr["q1"], vr["q2"]]))
            fmu.doStep(k * dt, dt)
    finally:
        fmu.terminate()
        fmu.freeInstance()
    held = simulate(model, np.tile([op[n] for n in INPUTS], (200, 1)), initial="model")
    np.testing.assert_allclose(rows, held, atol=TOL)
    zero = simulate(model, np.zeros((200, 4)), initial="model")
    assert np.abs(zero[-1] - held[-1]).max() > 1e-3  # 0 N is somewhere else entirely


def test_an_identified_model_is_named_after_its_file(tmp_path, small_data):
    from tendonkit.dataset import write_csv

    e = small_data[1].experiments[0]
    data = write_csv(
        tmp_path / "d.csv", {"t": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1], "y1": e.y[:, 0]}
    )
    out = tmp_path / "robot_arx_v2.json"
    assert main([
        "identify", str(data), "--inputs", "u1,u2", "--outputs", "y1", "-o", str(out)
    ]) == 0  # fmt: skip
    assert Model.load(out).name == "robot_arx_v2"


def test_reset_starts_the_same_run_again(tmp_path, identified, validation):
    """``fmi2Reset`` returns the slave to its initial state: the same inputs give the same run."""
    path = build_model_fmu(identified["arx_bilinear"], tmp_path / "m.fmu")
    md, fmu = open_slave(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    vin, vout = [vr[n] for n in INPUTS], [vr[n] for n in JOINT_OUTPUTS]
    dt = float(md.defaultExperiment.stepSize)

    def run() -> np.ndarray:
        rows = []
        for k in range(60):
            fmu.setReal(vin, list(validation[k]))
            rows.append(fmu.getReal(vout))
            fmu.doStep(k * dt, dt)
        return np.array(rows)

    try:
        first = run()
        fmu.reset()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        again = run()
    finally:
        fmu.terminate()
        fmu.freeInstance()
    np.testing.assert_array_equal(again, first)
    np.testing.assert_allclose(
        first, reference(identified["arx_bilinear"], validation[:60]), atol=TOL
    )
