"""The co-simulation master and the ``tendonkit mpc`` command, on short runs.

The closed-loop performance of the MPCs on identified models is tested in
``tests/integration/test_mpc_cosim.py``; here: references, the master's bookkeeping (alignment,
clipping, violations, fallbacks, output order), the controller dispatch and the command line.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.errors import FMUError, OptionError
from tendonkit.fmu.build import build_plant_fmu
from tendonkit.fmu.plant import Plant, PlantConfig
from tendonkit.mpc import Bounds, InputTarget, LinearMPC, NonlinearMPC, StepResult, Weights
from tendonkit.mpc.examples import tendon_sparse_map, two_mode_model
from tendonkit.mpc.nonlinear import SparseMapDynamics
from tendonkit.realize import to_state_space
from tendonkit.robot.cosim import (
    DEFAULTS,
    PAIR_SUMS,
    STEP,
    ControllerSettings,
    CosimResult,
    PlantFMU,
    controller_kind,
    make_controller,
    make_reference,
    open_loop,
    run,
)
from tendonkit.robot.kinematics import commanded_tensions, expand_joints, forward_kinematics
from tendonkit.schema import ARX, Block, Signal
from tendonkit.terms import Factor, Term
from tendonkit.testsystems import random_state_space

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_cosim")


@pytest.fixture(scope="session")
def plant_fmu(tmp_path_factory):
    return build_plant_fmu(tmp_path_factory.mktemp("cosim") / "plant.fmu")


@pytest.fixture(scope="session")
def model_json(tmp_path_factory):
    path = tmp_path_factory.mktemp("models") / "two_mode.json"
    two_mode_model(gain=0.0025).save(path)
    return path


# -- references --------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["petal", "circle", "step"])
def test_reference_is_consistent_with_the_kinematic_controller(kind):
    ref = make_reference(kind, duration=9.0, speed=0.05)
    n = round(9.0 / STEP)
    assert ref.q12.shape == (n, 2) and ref.ee.shape == (n, 3) and ref.u_open_loop.shape == (n, 4)
    np.testing.assert_allclose(ref.t, STEP * np.arange(n))
    # The open-loop commands are the static inverse of the joint references, and the
    # end-effector reference their forward kinematics (1e-9: same formulas, other call order).
    np.testing.assert_allclose(ref.u_open_loop, commanded_tensions(ref.q12, 105.0), atol=1e-9)
    np.testing.assert_allclose(ref.ee, forward_kinematics(expand_joints(ref.q12)), atol=1e-9)
    assert np.all(ref.u_open_loop >= 20.0) and np.all(ref.u_open_loop <= 190.0)


def test_petal_fills_the_duration_and_reaches_its_amplitude():
    ref = make_reference("petal", duration=30.0, amplitude=0.08, speed=0.04)
    radius = np.hypot(ref.ee[:, 0], ref.ee[:, 1])
    assert abs(radius.max() - 0.08) < 1e-3  # sampled rose tip: within 1 mm of A
    assert ref.info["laps"] > 1.0
    # the laps are chosen so that the curve ends in the final rest at the centre
    np.testing.assert_allclose(ref.q12[-5:], 0.0, atol=1e-12)


def test_preview_is_the_next_samples_and_holds_the_last():
    ref = make_reference("step", duration=1.5)
    prev = ref.preview(len(ref.t) - 3, 5)
    np.testing.assert_array_equal(prev[:2], ref.q12[-2:])
    np.testing.assert_array_equal(prev[2:], np.repeat(ref.q12[-1:], 3, axis=0))
    np.testing.assert_array_equal(ref.preview(0, 2), ref.q12[1:3])


def test_reference_errors_are_listed_together():
    with pytest.raises(OptionError) as err:
        make_reference("spiral", duration=-1.0, laps=0.0)
    text = str(err.value)
    assert "spiral" in text and "duration" in text and "laps" in text
    with pytest.raises(OptionError, match="amplitude"):
        make_reference("petal", amplitude=0.5)


# -- the master --------------------------------------------------------------------------------


class Scripted:
    """A controller that replays a script of inputs and records what it was given."""

    def __init__(self, inputs, output_names=("q1", "q2"), fallback_at=()):
        self.inputs = np.asarray(inputs, dtype=float)
        self.output_names = list(output_names)
        self.horizon = 3
        self.fallback_at = set(fallback_at)
        self.measured, self.previews, self.k = [], [], 0

    def reset(self, u0=None, y0=None):
        self.u0, self.y0, self.k = u0, y0, 0

    def step(self, y, r):
        self.measured.append(np.array(y))
        self.previews.append(np.array(r))
        u = self.inputs[min(self.k, len(self.inputs) - 1)]
        fallback = self.k in self.fallback_at
        self.k += 1
        return StepResult(u, "forced" if fallback else "Solved", 1e-4, fallback, None, 2e-4)


def test_open_loop_matches_the_plant_record(plant_fmu):
    """Row k holds the outputs read at t_k, before u_k: the alignment of Plant.record."""
    ref = make_reference("petal", duration=4.0, speed=0.05)
    res = open_loop(plant_fmu, ref)
    log = Plant(PlantConfig()).record(ref.u_open_loop)
    # 1e-12: the FMU runs the same code (tests/core/test_collect.py measures ~1e-16)
    np.testing.assert_allclose(res.y[:, :6], log["q"], atol=1e-12)
    np.testing.assert_allclose(res.truth[:, :2], log["q_true"][:, :2], atol=1e-12)
    np.testing.assert_array_equal(res.u, ref.u_open_loop)
    s = res.summary()
    e = log["q_true"][:, :2] - ref.q12
    assert s["rms_error_true_rad"]["q1"] == pytest.approx(np.sqrt(np.mean(e[:, 0] ** 2)))
    assert "solve_time_ms" not in s and s["fallbacks"] == 0 and s["input_bound_violations"] == 0


def test_master_clips_counts_violations_and_fallbacks(plant_fmu):
    ref = make_reference("step", duration=0.3)  # 10 steps
    script = np.full((10, 4), 105.0)
    script[2] = [250.0, 105.0, 10.0, 105.0]  # both bounds left: one violating step
    script[4, 1] = np.nan  # not finite: the previous input is held
    ctrl = Scripted(script, fallback_at=(6, 7))
    res = run(plant_fmu, ref, ctrl, name="scripted")
    assert res.violations == 2 and res.fallbacks == 2
    np.testing.assert_array_equal(res.u[2], [190.0, 105.0, 20.0, 105.0])
    np.testing.assert_array_equal(res.u[4], res.u[3])
    assert np.all((res.u >= 20.0) & (res.u <= 190.0))
    s = res.summary()
    assert s["statuses"] == {"Solved": 8, "forced": 2}
    assert s["solve_time_ms"]["median"] == pytest.approx(0.1)
    assert s["deadline_misses"] == 0 and s["samples"] == 10


def test_master_feeds_measurements_and_references_in_the_model_order(plant_fmu):
    ref = make_reference("step", duration=3.0)
    ctrl = Scripted(np.tile([125.0, 95.0, 85.0, 115.0], (100, 1)), output_names=("q2", "q1"))
    res = run(plant_fmu, ref, ctrl)
    np.testing.assert_array_equal(np.array(ctrl.measured), res.y[:, [1, 0]])
    k = 30
    np.testing.assert_array_equal(ctrl.previews[k], ref.preview(k, 3)[:, [1, 0]])
    np.testing.assert_array_equal(ctrl.y0, res.y[0, [1, 0]])
    with pytest.raises(OptionError, match="q3"):
        run(plant_fmu, ref, Scripted(np.zeros((1, 4)), output_names=("q1", "q3")))


def test_plant_errors(tmp_path, plant_fmu):
    with pytest.raises(FMUError, match="does not exist"):
        PlantFMU(tmp_path / "missing.fmu")
    with pytest.raises(OptionError, match="no parameter 'frictionn_on'"):
        PlantFMU(plant_fmu, {"frictionn_on": 1})


def test_effect_overrides_reach_the_plant(plant_fmu):
    ref = make_reference("step", duration=1.5)
    nominal = open_loop(plant_fmu, ref)
    delayed = open_loop(plant_fmu, ref, parameters={"delay_on": True, "delay_s": 0.09})
    assert delayed.parameters["delay_on"] is True
    # a 3-frame actuation delay shifts the response by exactly 3 samples (no other effect on)
    np.testing.assert_allclose(delayed.truth[3:, :2], nominal.truth[:-3, :2], atol=1e-12)


def test_summary_of_a_result_is_json_ready():
    ref = make_reference("step", duration=0.3)
    n = len(ref.t)
    res = CosimResult(
        "x", ref, np.zeros((n, 13)), np.zeros((n, 5)), np.zeros((n, 4)),
        np.full(n, 1e-3), np.full(n, 0.04), 0, 0, 0.01,
    )  # fmt: skip
    s = res.summary()
    json.dumps(s)
    assert s["deadline_misses"] == n  # 40 ms steps miss the 30 ms deadline
    assert s["realtime_factor"] == pytest.approx(ref.duration / 0.01)


# -- controller dispatch -----------------------------------------------------------------------


def test_controller_kind_dispatches_on_the_model():
    lin, nl = two_mode_model(), tendon_sparse_map()
    assert controller_kind(lin) == "linear" and controller_kind(nl) == "nonlinear"
    assert isinstance(make_controller(lin, ControllerSettings(horizon=5)), LinearMPC)
    ctrl = make_controller(nl, ControllerSettings(horizon=5))
    assert isinstance(ctrl, NonlinearMPC)
    # the pair-sum target: weight w on (u1 + u3 - 210)² + (u2 + u4 - 210)²
    w = DEFAULTS["nonlinear"]["pair_weight"]
    np.testing.assert_allclose(ctrl._S, w * PAIR_SUMS.T @ PAIR_SUMS)
    np.testing.assert_allclose(ctrl._u_target, 105.0)


def test_unsupported_models_are_refused_with_every_reason():
    m = two_mode_model()
    blocked = m.replace(
        input_blocks=(Block("dead_zone", "F1", {"threshold": 5.0, "center": 105.0}),),
        output_blocks=(Block("saturation", "q1", {"lower": -0.5, "upper": 0.5}),),
    )
    with pytest.raises(OptionError) as err:
        controller_kind(blocked)
    assert "dead_zone" in str(err.value) and "saturation" in str(err.value)
    three = random_state_space(4, 3, 2).replace(outputs=(Signal("q1"), Signal("q2")))
    with pytest.raises(OptionError, match="four tendon forces"):
        controller_kind(three)
    renamed = m.replace(outputs=(Signal("q1"), Signal("x")))
    with pytest.raises(OptionError, match="q1 and q2"):
        controller_kind(renamed)


def test_arx_with_terms_is_refused():
    arx = ARX(
        A=(0.5 * np.eye(2),),
        B=(1e-3 * np.ones((2, 4)),),
        nk=(1, 1, 1, 1),
        terms=(Term((Factor("q1", fn="sin", lag=1),)),),
        term_coefficients=np.ones((1, 2)),
    )
    m = two_mode_model().replace(representation=arx)
    with pytest.raises(OptionError, match="nonlinear terms"):
        controller_kind(m)


# -- command line ------------------------------------------------------------------------------


def test_cli_runs_the_mpc_and_reports(tmp_path, plant_fmu, model_json, capsys):
    out, figs = tmp_path / "out.json", tmp_path / "figs"
    code = main(
        ["mpc", str(model_json), "--plant", str(plant_fmu), "--reference", "step",
         "--duration", "3", "--horizon", "10", "--open-loop", "--json", str(out),
         "--plot", str(figs), "--effect", "N", "--seed", "3"]
    )  # fmt: skip
    assert code == 0
    data = json.loads(out.read_text())
    mpc = data["mpc"]
    assert data["controller"] == "linear MPC" and data["settings"]["horizon"] == 10
    assert data["plant_overrides"] == {"noise_on": True, "seed": 3}
    assert data["plant_effects"] == ["noise"]
    for key in ("rms_error_rad", "rms_error_true_rad"):
        assert set(mpc[key]) == {"q1", "q2"}
    assert set(mpc["solve_time_ms"]) == {"median", "p99", "max"}
    assert mpc["input_bound_violations"] == 0 and mpc["fallbacks"] == 0
    assert mpc["deadline_misses"] >= 0 and mpc["mean_ee_error_cm"] > 0
    assert "open_loop" in data and set(data["improvement_true_percent"]) == {"q1", "q2"}
    assert (figs / "fig5_tracking.png").stat().st_size > 10_000
    assert "RMS joint error" in capsys.readouterr().out


def test_cli_errors_are_one_message_with_exit_2(tmp_path, model_json):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    proc = subprocess.run(
        [sys.executable, "-m", "tendonkit.cli", "mpc", str(bad), "--reference", "petal",
         "--plant", str(tmp_path / "none.fmu"), "--horizon", "0", "--R", "-1",
         "--effect", "QQ", "--json", str(tmp_path / "no" / "out.json")],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    for part in ("bad.json", "--horizon", "--R", "none.fmu", "out.json", "QQ"):
        assert part in proc.stderr
    proc = subprocess.run(
        [sys.executable, "-m", "tendonkit.cli", "mpc", str(model_json), "--reference", "spiral"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert proc.returncode == 2 and "spiral" in proc.stderr and "Traceback" not in proc.stderr


def test_cli_checks_the_figures_folder_before_the_co_simulation(tmp_path, model_json, capsys):
    taken = tmp_path / "s.csv"
    taken.write_text("a file, not a folder")
    out = tmp_path / "mp.json"
    args = ["mpc", str(model_json), "--reference", "step", "--duration", "0.3"]
    assert main([*args, "--plot", str(taken), "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--plot" in err and "exists and is not a folder" in err and "Traceback" not in err
    assert taken.read_text() == "a file, not a folder" and not out.exists()
    assert main([*args, "--plot", str(out), "--json", str(out)]) == 2
    assert "--json and --plot name the same path" in capsys.readouterr().err


def test_cli_refuses_a_model_it_cannot_control(tmp_path, capsys):
    path = tmp_path / "m.json"
    two_mode_model().replace(outputs=(Signal("q1"), Signal("tilt"))).save(path)
    code = main(["mpc", str(path), "--reference", "step", "--effect", "nonsense_on=1"])
    assert code == 2
    err = capsys.readouterr().err
    assert "q1 and q2" in err and "nonsense_on" in err


# -- MPC options added for the co-simulation ---------------------------------------------------


def _closed_loop(ctrl, model, ref, steps, u0):
    """The controller against its own model (exact plant), returning the applied inputs."""
    ss = to_state_space(model)
    x = np.linalg.lstsq(np.eye(len(ss.A)) - ss.A, ss.B @ u0, rcond=None)[0]
    ctrl.reset(u0, ss.C @ x)
    U = []
    for _ in range(steps):
        u = ctrl.step(ss.C @ x, ref).u
        x = ss.A @ x + ss.B @ u
        U.append(u)
    return np.array(U), ss.C @ x


def test_input_target_anchors_the_pair_sums():
    """Without coupling the angles see only F1 - F3 and F2 - F4: the pair sums are free."""
    model = two_mode_model(coupling=0.0)
    u0 = np.array([125.0, 125.0, 125.0, 125.0])  # pair sums 250 N
    ref = np.array([[0.1, -0.05]])
    free, _ = _closed_loop(
        LinearMPC(model, horizon=10, weights=Weights(R=0.0001)), model, ref, 80, u0
    )
    target = InputTarget(1e-3 * PAIR_SUMS.T @ PAIR_SUMS, 105.0)
    held, y = _closed_loop(
        LinearMPC(model, horizon=10, weights=Weights(R=0.0001, input_target=target)),
        model,
        ref,
        80,
        u0,
    )
    # 1e-6 rad: exact model, offset-free, 80 steps of a well-damped loop
    np.testing.assert_allclose(y, ref[0], atol=1e-6)
    np.testing.assert_allclose(held[-1] @ PAIR_SUMS.T, 210.0, atol=0.5)
    assert np.all(np.abs(free[-1] @ PAIR_SUMS.T - 250.0) < 1.0)  # nothing moves them back


def test_du_max_limits_every_move():
    model = two_mode_model()
    u0 = np.full(4, 105.0)
    ref = np.array([[0.2, -0.2]])
    fast, _ = _closed_loop(
        LinearMPC(model, horizon=10, weights=Weights(R=0.0001)), model, ref, 40, u0
    )
    limited, _ = _closed_loop(
        LinearMPC(model, horizon=10, weights=Weights(R=0.0001), bounds=Bounds(du_max=2.0)),
        model,
        ref,
        40,
        u0,
    )
    moves = np.abs(np.diff(np.vstack([u0, limited]), axis=0))
    assert moves.max() <= 2.0 + 1e-6  # solver tolerance on the scaled inputs
    assert np.abs(np.diff(np.vstack([u0, fast]), axis=0)).max() > 10.0  # the limit is active
    with pytest.raises(OptionError, match="du_max"):
        LinearMPC(model, bounds=Bounds(du_max=0.0))


def test_linearising_along_the_plan_or_a_rollout_tracks_alike():
    model = tendon_sparse_map()
    ref = np.array([[0.15, -0.1]])
    finals = []
    for how in ("plan", "rollout"):
        ctrl = NonlinearMPC(model, horizon=10, linearize_along=how, weights=Weights(R=0.0001))
        ctrl.reset(np.full(4, 105.0), np.zeros(2))
        dyn = SparseMapDynamics(model)
        z = dyn.initial_state(np.zeros(2), np.full(4, 105.0))
        for _ in range(60):
            u = ctrl.step(dyn.C @ z, ref).u
            z = dyn.step(z, u)
        finals.append(dyn.C @ z)
    # both converge on the exact model (1e-4 rad: offset-free, 60 steps)
    np.testing.assert_allclose(finals[0], ref[0], atol=1e-4)
    np.testing.assert_allclose(finals[1], ref[0], atol=1e-4)
    with pytest.raises(OptionError, match="linearize_along"):
        NonlinearMPC(model, linearize_along="midpoint")


def test_cli_builds_and_caches_the_default_plant(tmp_path, model_json, monkeypatch):
    monkeypatch.setenv("TENDONKIT_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "out.json"
    args = ["mpc", str(model_json), "--reference", "step", "--duration", "0.6"]
    assert main([*args, "--preset", "paper_like", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert set(data["plant_effects"]) == {
        "friction", "delay", "forcelag", "camera", "gravity (horiz_tilt)"
    }  # fmt: skip
    assert data["plant"].startswith(str(tmp_path / "cache"))
    assert main([*args, "--preset", "paper_like", "--json", str(out)]) == 0  # from the cache
    assert len(list((tmp_path / "cache").rglob("*.fmu"))) == 1


def test_cli_warns_when_the_model_maps_measured_tensions(tmp_path, plant_fmu, capsys):
    from tendonkit.schema import Signal

    model = two_mode_model()
    model = model.replace(inputs=tuple(Signal(f"T{i}", "N") for i in range(1, 5)))
    path = tmp_path / "t_model.json"
    model.save(path)
    code = main(
        ["mpc", str(path), "--plant", str(plant_fmu), "--reference", "step",
         "--duration", "1", "--horizon", "5", "--no-progress"]
    )  # fmt: skip
    assert code == 0
    assert "warning: model" in capsys.readouterr().err
