"""MPC controllers: tracking, offset-free, constraints, DPP, design vs fast path, fallback.

The plants are small known systems shaped like the robot (tendonkit.mpc.examples): linear
pan/tilt modes at 3.6 and 4.7 Hz driven by tension differences (0.006 rad/N, operating point
105 N), and a two-state sparse map with ``u·cos(q)`` and ``u·sin(q)`` terms.  Weights: the
tests use R = 1e-4 or 1e-3 (N⁻²) so that the loops settle within a second; the default R = 0.1
with Q = 1 rad⁻² is much slower on this scale (a time constant of seconds).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from tendonkit.errors import DataError, OptionError
from tendonkit.mpc import (
    Bounds,
    Estimator,
    LinearMPC,
    NoiseCovariance,
    NonlinearMPC,
    Solver,
    StepResult,
    Weights,
)
from tendonkit.mpc.examples import tendon_sparse_map, two_mode_model
from tendonkit.mpc.nonlinear import SparseMapDynamics, nonlinear_problems
from tendonkit.realize import to_state_space
from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.simulate import simulate
from tendonkit.terms import Factor, Term

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_mpc")

U0 = np.full(4, 105.0)


class LinearPlant:
    """``x+ = Ax + B(u0 + gain (u - u0))``, ``y = Cx + bias``: a model with a mismatch."""

    def __init__(self, model: Model, gain: float = 1.0, bias: float = 0.0) -> None:
        ss = to_state_space(model)
        self.A, self.B, self.C = ss.A, ss.B, ss.C
        self.gain, self.bias = gain, bias
        self.x = np.linalg.solve(np.eye(self.A.shape[0]) - self.A, self.B @ U0)

    def output(self) -> np.ndarray:
        return self.C @ self.x + self.bias

    def apply(self, u: np.ndarray) -> None:
        self.x = self.A @ self.x + self.B @ (U0 + self.gain * (u - U0))


class MapPlant:
    """A sparse-map plant, stepped with :class:`SparseMapDynamics`, with an output bias."""

    def __init__(self, model: Model, bias: float = 0.0) -> None:
        self.dyn = SparseMapDynamics(model)
        self.x = np.zeros(self.dyn.nz)
        self.bias = bias

    def output(self) -> np.ndarray:
        return self.dyn.C @ self.x + self.bias

    def apply(self, u: np.ndarray) -> None:
        self.x = self.dyn.step(self.x, u)


def closed_loop(ctrl, plant, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[StepResult]]:
    """Run ``len(ref)`` samples; ``ref[k]`` is the reference for the output at sample k."""
    ctrl.reset(U0, plant.output())
    Y, U, results = [], [], []
    for k in range(len(ref)):
        y = plant.output()
        res = ctrl.step(y, ref[k + 1 : k + 1 + ctrl.horizon] if k + 1 < len(ref) else ref[-1:])
        plant.apply(res.u)
        Y.append(y)
        U.append(res.u)
        results.append(res)
    return np.array(Y), np.array(U), results


def step_ref(n: int = 150, at: int = 10, value=(0.4, -0.3)) -> np.ndarray:
    ref = np.zeros((n, 2))
    ref[at:] = value
    return ref


def sine_ref(n: int = 300) -> np.ndarray:
    t = np.arange(n) * 0.03
    return np.c_[0.5 * np.sin(2 * np.pi * 0.5 * t), 0.5 * np.cos(2 * np.pi * 0.4 * t) - 0.1]


@pytest.fixture(scope="session")
def robot():
    return two_mode_model()


# -- tracking and offset-free ----------------------------------------------------------------


def test_step_and_smooth_reference_are_tracked(robot):
    ctrl = LinearMPC(robot, weights=Weights(R=0.001))
    Y, U, _ = closed_loop(ctrl, LinearPlant(robot), step_ref())
    # Exact model, no noise: the step is reached to solver accuracy within 2 s.
    assert np.max(np.abs(Y[-20:] - [0.4, -0.3])) < 1e-4
    ref = sine_ref()
    ctrl = LinearMPC(robot, weights=Weights(R=0.0001))
    Y, U, res = closed_loop(ctrl, LinearPlant(robot), ref)
    # With preview the smooth reference is followed closely once the loop has started
    # (measured 0.004 rad rms; the rest is the price of input moves at R = 1e-4).
    assert np.sqrt(np.mean((Y[50:] - ref[50:]) ** 2)) < 0.01
    assert ctrl.n_fallbacks == 0 and np.all((U >= 20.0) & (U <= 190.0))
    assert res[-1].predicted_y is not None and res[-1].predicted_y.shape == (20, 2)


@pytest.mark.parametrize("disturbance", ["output", "input"])
def test_offset_free_with_gain_mismatch_and_bias(robot, disturbance):
    # The plant's gain is 30 % higher than the model's and its outputs read 0.05 rad high.
    ctrl = LinearMPC(robot, weights=Weights(R=0.001), estimator=Estimator(disturbance=disturbance))
    Y, _, _ = closed_loop(ctrl, LinearPlant(robot, gain=1.3, bias=0.05), step_ref(200))
    assert np.max(np.abs(Y[-10:] - [0.4, -0.3])) < 1e-4
    # The disturbance estimate explains the mismatch (0.05 rad bias plus 30 % of the step).
    assert ctrl.disturbance_estimate.shape == (2,)


def test_without_disturbance_model_an_offset_remains(robot):
    ctrl = LinearMPC(robot, weights=Weights(R=0.001), estimator=Estimator(disturbance="none"))
    Y, _, _ = closed_loop(ctrl, LinearPlant(robot, gain=1.3, bias=0.05), step_ref(200))
    assert np.max(np.abs(Y[-10:] - [0.4, -0.3])) > 0.05


# -- constraints -------------------------------------------------------------------------------


def test_inputs_within_bounds_and_soft_output_bound_keeps_feasibility(robot):
    # The reference (1.3 rad) lies outside the soft bound y_max = 0.5 rad, and the plant starts
    # outside it too (0.8 rad): every step must still solve, and the bound must be respected
    # up to what the slack penalty allows.
    ctrl = LinearMPC(
        robot,
        weights=Weights(R=0.0001),
        bounds=Bounds(u_min=30.0, u_max=180.0, y_min=-0.5, y_max=0.5),
    )
    plant = LinearPlant(robot)
    plant.x = plant.x + np.linalg.pinv(plant.C) @ np.array([0.8, 0.0])
    ref = np.tile([1.3, -1.3], (120, 1))
    Y, U, _res = closed_loop(ctrl, plant, ref)
    assert ctrl.n_fallbacks == 0
    assert np.all(U >= 30.0) and np.all(U <= 180.0)
    assert np.max(np.abs(Y[40:])) < 0.5 + 1e-3
    assert np.max(np.abs(Y[-1])) > 0.49  # pushed to the bound, not beyond


def test_unreachable_reference_saturates_inputs_without_failure(robot):
    ctrl = LinearMPC(
        robot, horizon=10, weights=Weights(R=0.0001), bounds=Bounds(y_min=-np.inf, y_max=np.inf)
    )
    _Y, U, _ = closed_loop(ctrl, LinearPlant(robot), np.tile([3.0, -3.0], (60, 1)))
    assert ctrl.n_fallbacks == 0
    assert np.all(U >= 20.0) and np.all(U <= 190.0)
    assert np.isclose(U[-1, 0], 190.0) and np.isclose(U[-1, 2], 20.0)


# -- the problem and its two solution paths ----------------------------------------------------


def test_problems_are_dpp(robot):
    assert LinearMPC(robot, horizon=5, solver=Solver(fast=False)).problem.is_dpp()
    assert LinearMPC(
        robot, horizon=5, solver=Solver(fast=False, formulation="condensed")
    ).problem.is_dpp()
    assert NonlinearMPC(tendon_sparse_map(), horizon=5, solver=Solver(fast=False)).problem.is_dpp()


@pytest.mark.parametrize("solver", ["clarabel", "osqp"])
def test_design_and_fast_paths_give_the_same_inputs(robot, solver):
    ref = sine_ref(80)
    kw = dict(R=1e-3, solver=solver, horizon=15)
    _, U_fast, _ = closed_loop(LinearMPC(robot, fast=True, **kw), LinearPlant(robot, 1.2), ref)
    _, U_cvx, _ = closed_loop(LinearMPC(robot, fast=False, **kw), LinearPlant(robot, 1.2), ref)
    # Same data to the same solver; 1e-3 N covers OSQP's 1e-5 tolerances on ~100 N inputs.
    np.testing.assert_allclose(U_fast, U_cvx, atol=1e-3)


def test_nonlinear_design_and_fast_paths_give_the_same_inputs():
    model, ref = tendon_sparse_map(), sine_ref(60)
    _, U_fast, _ = closed_loop(
        NonlinearMPC(model, horizon=10, weights=Weights(R=0.001)), MapPlant(model), ref
    )
    _, U_cvx, _ = closed_loop(
        NonlinearMPC(model, horizon=10, weights=Weights(R=0.001), solver=Solver(fast=False)),
        MapPlant(model),
        ref,
    )
    np.testing.assert_allclose(U_fast, U_cvx, atol=1e-3)


def test_condensed_and_sparse_formulations_agree(robot):
    ref = step_ref(40)
    _, U_s, _ = closed_loop(
        LinearMPC(robot, solver=Solver(formulation="sparse"), weights=Weights(R=0.001)),
        LinearPlant(robot),
        ref,
    )
    _, U_c, _ = closed_loop(
        LinearMPC(robot, solver=Solver(formulation="condensed"), weights=Weights(R=0.001)),
        LinearPlant(robot),
        ref,
    )
    # Same optimum, different KKT systems: agreement to the solver tolerance.
    np.testing.assert_allclose(U_s, U_c, atol=1e-3)


# -- models --------------------------------------------------------------------------------------


def _exact_arx(model: Model) -> Model:
    """The two-mode model as an ARX(2, 2) model (each output is one second-order mode)."""
    ss = model.representation
    assert isinstance(ss, StateSpace)
    A1, A2, B1, B2 = np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 4)), np.zeros((2, 4))
    for i in range(2):
        Ai, Bi, ci = (
            ss.A[2 * i : 2 * i + 2, 2 * i : 2 * i + 2],
            ss.B[2 * i : 2 * i + 2],
            ss.C[i, 2 * i : 2 * i + 2],
        )
        tr, det = np.trace(Ai), np.linalg.det(Ai)
        A1[i, i], A2[i, i] = -tr, det
        B1[i], B2[i] = ci @ Bi, ci @ (Ai - tr * np.eye(2)) @ Bi
    rep = ARX(A=(A1, A2), B=(B1, B2), nk=(1, 1, 1, 1))
    return model.replace(name="two-mode ARX", representation=rep)


def test_arx_model_is_realized_reduced_and_controls_like_its_state_space(robot):
    arx = _exact_arx(robot)
    ref = step_ref(60)
    ctrl_arx = LinearMPC(arx, weights=Weights(R=0.001))
    assert ctrl_arx.prediction.n_realized == 12 and ctrl_arx.n_states == 4  # minreal
    _, U_arx, _ = closed_loop(ctrl_arx, LinearPlant(robot), ref)
    _, U_ss, _ = closed_loop(LinearMPC(robot, weights=Weights(R=0.001)), LinearPlant(robot), ref)
    # Same input-output model and a consistent initial state: the same inputs.
    np.testing.assert_allclose(U_arx, U_ss, atol=1e-3)
    unreduced = LinearMPC(arx, reduce="none", horizon=5, weights=Weights(R=0.001))
    assert unreduced.n_states == 12


def test_balanced_truncation_still_tracks_offset_free():
    from tendonkit.mpc.examples import random_tendon_model

    truth = random_tendon_model(8, seed=0)
    ctrl = LinearMPC(truth, reduce=4, weights=Weights(R=0.001))
    assert ctrl.n_states == 4 and ctrl.prediction.n_realized == 8
    Y, _, _ = closed_loop(ctrl, LinearPlant(truth), step_ref(120, value=(0.3, -0.2)))
    # The truncation error is a model/plant mismatch, which the disturbance model removes.
    assert np.max(np.abs(Y[-10:] - [0.3, -0.2])) < 1e-4


def test_input_delay_blocks_are_realized(robot):
    delayed = robot.replace(
        input_blocks=tuple(Block("delay", f"F{i}", {"samples": 2.0}) for i in range(1, 5))
    )
    ctrl = LinearMPC(delayed, weights=Weights(R=0.001))
    plant = LinearPlant(delayed)
    Y, _, _ = closed_loop(ctrl, plant, step_ref(120))
    assert np.max(np.abs(Y[-10:] - [0.4, -0.3])) < 1e-3


class LaggedPlant:
    """``plant`` behind a first-order lag on every input, written out here (not realised by
    tendonkit): ``v[k] = a v[k-1] + (1 - a) u[k-1]`` from rest at ``U0``."""

    def __init__(self, plant: LinearPlant, poles: list[float]) -> None:
        self.plant, self.a, self.v = plant, np.array(poles), U0.copy()

    def output(self) -> np.ndarray:
        return self.plant.output()

    def apply(self, u: np.ndarray) -> None:
        self.plant.apply(self.v)
        self.v = self.a * self.v + (1.0 - self.a) * u


def test_first_order_lag_blocks_are_realized(robot):
    """A force-controller lag (what diagnose's actuator_lag adds: first_order_lag input blocks)
    is linear: the MPC realises each lag as a state and tracks the lagged plant; the same MPC
    on the model without the lag is slower and overshoots on it."""
    poles = [0.8, 0.6, 0.8, 0.6]
    lagged = robot.replace(
        input_blocks=tuple(
            Block("first_order_lag", f"F{i}", {"pole": p}) for i, p in enumerate(poles, 1)
        )
    )
    assert (
        lagged.is_linear and to_state_space(lagged).A.shape[0] == robot.representation.n_states + 4
    )
    errors = {}
    for name, model in (("lagged", lagged), ("unlagged", robot)):
        ctrl = LinearMPC(model, weights=Weights(R=0.001))
        Y, _, _ = closed_loop(ctrl, LaggedPlant(LinearPlant(robot), poles), step_ref(150))
        errors[name] = float(np.sqrt(np.mean((Y[10:] - [0.4, -0.3]) ** 2)))
        if name == "lagged":
            assert np.max(np.abs(Y[-10:] - [0.4, -0.3])) < 1e-3
    assert errors["lagged"] < errors["unlagged"]


def test_subset_of_signals_and_measurement_mapping(robot):
    # Only the pan pair drives q1; the controller reads q1 from a mapping with extra signals.
    ss = robot.representation
    assert isinstance(ss, StateSpace)
    sub = Model(
        name="pan only",
        dt=robot.dt,
        inputs=(Signal("F1", "N"), Signal("F3", "N")),
        outputs=(Signal("q1", "rad"),),
        representation=StateSpace(
            A=ss.A[:2, :2], B=ss.B[:2, [0, 2]], C=ss.C[:1, :2], D=np.zeros((1, 2))
        ),
    )
    ctrl = LinearMPC(sub, horizon=10, weights=Weights(R=0.001))
    ctrl.reset([105.0, 105.0], {"q1": 0.0, "q2": 0.3})
    res = ctrl.step({"q1": 0.0, "q2": 0.3, "x": 1.0}, [[0.2]])
    assert res.u.shape == (2,) and set(res.as_dict()) == {"F1", "F3"}
    assert res.as_dict()["F1"] > 105.0 > res.as_dict()["F3"]
    with pytest.raises(DataError, match="q1"):
        ctrl.step({"q2": 0.1}, [[0.2]])


def test_nonlinear_models_and_blocks_are_refused_by_the_linear_mpc(robot):
    with pytest.raises(OptionError, match="sparse_map"):
        LinearMPC(tendon_sparse_map())
    dz = robot.replace(input_blocks=(Block("dead_zone", "F1", {"threshold": 1.0, "center": 0.0}),))
    with pytest.raises(
        OptionError, match=r"dead_zone.*only 'delay', 'first_order_lag' and 'second_order_section'"
    ):
        LinearMPC(dz)
    with pytest.raises(OptionError, match="sparse_map models"):
        NonlinearMPC(robot)


def test_invalid_options_are_all_reported(robot):
    with pytest.raises(OptionError) as err:
        LinearMPC(
            robot,
            horizon=0,
            bounds=Bounds(u_min=200),
            solver=Solver(name="gurobi"),
            estimator=Estimator(disturbance="integral"),
            weights=Weights(R=-1),
        )
    text = str(err.value)
    for word in ("horizon", "u_min", "solver", "disturbance", "R must"):
        assert word in text
    with pytest.raises(OptionError, match="measurement"):
        NoiseCovariance(measurement=0.0)


# -- nonlinear MPC -----------------------------------------------------------------------------


def _linearization(model: Model) -> Model:
    """Linearisation at q = 0, u = 105 N as an ARX(1, 1) model with an offset."""
    dyn = SparseMapDynamics(model)
    F, A, B = dyn.linearize(np.zeros((1, 2)), U0[None])
    rep = ARX(A=(-A[0],), B=(B[0],), nk=(1, 1, 1, 1), offset=F[0] - B[0] @ U0)
    return Model(
        name="linearised",
        dt=model.dt,
        inputs=model.inputs,
        outputs=model.outputs,
        representation=rep,
    )


def test_nonlinear_mpc_tracks_and_beats_linear_mpc_on_its_linearization():
    model = tendon_sparse_map(bend=1.5)
    ref = sine_ref(250)
    nmpc = NonlinearMPC(model, weights=Weights(R=0.0001))
    Y_n, U_n, res = closed_loop(nmpc, MapPlant(model), ref)
    Y_l, _, _ = closed_loop(
        LinearMPC(_linearization(model), weights=Weights(R=0.0001)), MapPlant(model), ref
    )
    rms_n = np.sqrt(np.mean((Y_n[50:] - ref[50:]) ** 2))
    rms_l = np.sqrt(np.mean((Y_l[50:] - ref[50:]) ** 2))
    assert nmpc.n_fallbacks == 0
    assert rms_n < 0.01  # 2 % of the 0.5 rad amplitude
    assert rms_n < 0.5 * rms_l  # measured: about 0.005 vs 0.03
    assert np.all(U_n >= 20.0) and np.all(U_n <= 190.0)
    assert max(r.step_time_s for r in res) < 1.0  # sanity only; timing is benchmarked


def test_nonlinear_mpc_is_offset_free():
    model = tendon_sparse_map()
    plant_model = tendon_sparse_map(arm=0.0018, pole=0.88)  # 20 % stronger, faster plant
    ctrl = NonlinearMPC(model, weights=Weights(R=0.001))
    Y, _, _ = closed_loop(ctrl, MapPlant(plant_model, bias=0.04), step_ref(200, value=(0.5, -0.4)))
    assert np.max(np.abs(Y[-10:] - [0.5, -0.4])) < 1e-4
    free = NonlinearMPC(
        model, horizon=10, weights=Weights(R=0.001), estimator=Estimator(disturbance="none")
    )
    Y, _, _ = closed_loop(free, MapPlant(plant_model, bias=0.04), step_ref(200, value=(0.5, -0.4)))
    assert np.max(np.abs(Y[-10:] - [0.5, -0.4])) > 0.02


def _lagged_map() -> Model:
    """A map with a lagged state, a differenced input, a delayed input (block) and a term of the
    difference of an input and the state (between two bodies)."""
    terms = (
        Term((Factor("x"),)),
        Term((Factor("x", lag=1),)),
        Term((Factor("u", fn="tanh", scale=0.1), Factor("x", fn="cos"))),
        Term((Factor("v", diff=1), Factor("x", fn="sin"))),
        Term(()),
        Term((Factor("v", fn="tanh", minus="x", lag=1, scale=2.0),)),
    )
    coef = np.array([[1.2], [-0.35], [0.08], [0.01], [0.005], [0.02]])
    return Model(
        name="lagged",
        dt=0.03,
        inputs=(Signal("u"), Signal("v")),
        outputs=(Signal("y"),),
        states=(Signal("x"),),
        representation=SparseMap(terms=terms, coefficients=coef, output_states=(0,)),
        input_blocks=(Block("delay", "u", {"samples": 2.0}),),
    )


def test_a_difference_of_signals_behind_different_delays_is_refused():
    """The rollout reads each factor at one lag: ``u - v`` with ``u`` delayed and ``v`` not
    cannot be read so, and is refused with a message that names the term."""
    model = _lagged_map()
    rep = model.representation
    terms = (*rep.terms, Term((Factor("u", minus="v", fn="sat", param=0.5),)))
    coef = np.vstack([rep.coefficients, [[0.01]]])
    bad = model.replace(representation=replace(rep, terms=terms, coefficients=coef))
    with pytest.raises(OptionError, match=r"sat\(\(u-v\);0.5\).*different input delays"):
        SparseMapDynamics(bad)
    assert any("sat((u-v);0.5)" in p for p in nonlinear_problems(bad))
    assert not nonlinear_problems(model)


def test_sparse_map_dynamics_match_simulation_and_jacobians_are_exact():
    model = _lagged_map()
    dyn = SparseMapDynamics(model)
    assert dyn.nz == 2 + 2 * 2  # x[k], x[k-1]; u and v over two past samples (delay 2)
    rng = np.random.default_rng(4)
    U = rng.uniform(-1, 1, size=(40, 2))
    x0 = 0.1
    y_sim = simulate(model, U, initial=np.array([x0]))[:, 0]
    z0 = dyn.initial_state(np.array([x0]), U[0])
    Z = dyn.rollout(z0, U[:-1])
    # simulate() pads the past with the first sample, as initial_state does.
    np.testing.assert_allclose(Z[:, 0], y_sim, atol=1e-12)
    # the compiled rollout equals the step-by-step one, every part of the augmented state,
    # also from a state whose histories differ from its current values
    np.testing.assert_allclose(Z, dyn.rollout_reference(z0, U[:-1]), rtol=1e-12, atol=1e-14)
    z1 = z0 + rng.normal(0, 0.1, z0.shape)
    np.testing.assert_allclose(
        dyn.rollout(z1, U[5:]), dyn.rollout_reference(z1, U[5:]), rtol=1e-12, atol=1e-14
    )
    _F, A, B = dyn.linearize(Z[:-1], U[:-1])
    eps = 1e-6
    for j in (3, 17):
        for i in range(dyn.nz):
            dz = np.zeros(dyn.nz)
            dz[i] = eps
            fd = (dyn.step(Z[j] + dz, U[j]) - dyn.step(Z[j] - dz, U[j])) / (2 * eps)
            np.testing.assert_allclose(A[j][:, i], fd, atol=1e-7)
        for i in range(2):
            du = np.zeros(2)
            du[i] = eps
            fd = (dyn.step(Z[j], U[j] + du) - dyn.step(Z[j], U[j] - du)) / (2 * eps)
            np.testing.assert_allclose(B[j][:, i], fd, atol=1e-7)


def test_nonlinear_mpc_controls_a_lagged_map():
    model = _lagged_map()
    ctrl = NonlinearMPC(
        model,
        horizon=12,
        weights=Weights(R=0.001),
        bounds=Bounds(u_min=-10, u_max=10, y_min=-2, y_max=2),
    )
    plant = MapPlant(model)
    ctrl.reset(np.zeros(2), plant.output())
    for _k in range(150):
        res = ctrl.step(plant.output(), [[0.3]])
        plant.apply(res.u)
    assert abs(plant.output()[0] - 0.3) < 1e-3 and ctrl.n_fallbacks == 0


# -- fallback ----------------------------------------------------------------------------------


def test_forced_solver_failure_holds_the_last_input(robot):
    ctrl = LinearMPC(
        robot,
        horizon=10,
        weights=Weights(R=0.001),
        solver=Solver(failure_hook=lambda k: k in (20, 21, 22)),
    )
    _, U, res = closed_loop(ctrl, LinearPlant(robot), step_ref(60))
    assert ctrl.n_fallbacks == 3
    assert [r.fallback for r in res].count(True) == 3
    assert res[20].status == "forced failure" and res[20].predicted_y is None
    np.testing.assert_array_equal(U[20], U[19])
    np.testing.assert_array_equal(U[22], U[19])
    assert not res[23].fallback


def test_solver_exceptions_and_bad_measurements_fall_back(robot, monkeypatch):
    ctrl = LinearMPC(robot, horizon=5, weights=Weights(R=0.001))
    ctrl.reset(U0, np.zeros(2))
    first = ctrl.step(np.zeros(2), [[0.2, 0.0]])

    def broken():
        raise RuntimeError("no convergence")

    monkeypatch.setattr(ctrl._qp, "solve", broken)
    res = ctrl.step(np.zeros(2), [[0.2, 0.0]])
    assert res.fallback and "no convergence" in res.status
    np.testing.assert_array_equal(res.u, first.u)
    monkeypatch.undo()
    res = ctrl.step(np.array([np.nan, 0.0]), [[0.2, 0.0]])
    assert res.fallback and res.status == "invalid measurement"
    assert ctrl.n_fallbacks == 2 and ctrl.n_steps == 3
    assert not ctrl.step(np.zeros(2), [[0.2, 0.0]]).fallback


def test_reference_is_padded_and_checked(robot):
    ctrl = LinearMPC(robot, horizon=8, weights=Weights(R=0.001))
    res = ctrl.step(np.zeros(2), np.array([[0.1, 0.1], [0.2, 0.2]]))  # resets itself
    assert res.predicted_y is not None and res.predicted_y.shape == (8, 2)
    assert not res.fallback
    with pytest.raises(DataError, match="reference"):
        ctrl.step(np.zeros(2), np.zeros((3, 3)))


def test_noise_model_with_innovation_gain_is_used(robot):
    ss = robot.representation
    assert isinstance(ss, StateSpace)
    from tendonkit.predict import kalman_gain

    K = kalman_gain(ss.A, ss.C, 1e-3 * np.eye(4), 1e-4 * np.eye(2))
    with_k = robot.replace(representation=replace(ss, K=K))
    ctrl = LinearMPC(
        with_k, reduce="none", weights=Weights(R=0.001), estimator=Estimator(disturbance="none")
    )
    # Without disturbances the predictor gain is the model's own K.
    np.testing.assert_allclose(ctrl._L, K, atol=1e-8)
    Y, _, _ = closed_loop(ctrl, LinearPlant(with_k), step_ref(80))
    assert np.max(np.abs(Y[-5:] - [0.4, -0.3])) < 1e-3


# -- option objects and the keywords of 0.1 ------------------------------------------------------


def test_keywords_of_0_1_give_the_same_controller_with_one_warning(robot):
    new = LinearMPC(
        robot,
        horizon=8,
        weights=Weights(R=0.01, slack=(100.0, 10.0)),
        bounds=Bounds(u_min=30.0, u_max=180.0, du_max=5.0),
        estimator=Estimator(disturbance="input", noise=NoiseCovariance(1e-3, 1e-4, 1e-5)),
        solver=Solver(name="osqp", formulation="condensed"),
    )
    with pytest.warns(DeprecationWarning, match="keyword form of tendonkit 0.1") as record:
        old = LinearMPC(
            robot, horizon=8, R=0.01, slack_weight=(100.0, 10.0), u_min=30.0, u_max=180.0,
            du_max=5.0, disturbance="input", noise=NoiseCovariance(1e-3, 1e-4, 1e-5),
            solver="osqp", formulation="condensed",
        )  # fmt: skip
    assert len([w for w in record if w.category is DeprecationWarning]) == 1
    assert old.options == new.options
    ref = step_ref()
    _, U_new, _ = closed_loop(new, LinearPlant(robot), ref)
    _, U_old, _ = closed_loop(old, LinearPlant(robot), ref)
    np.testing.assert_array_equal(U_new, U_old)


def test_option_mistakes_are_listed_together(robot):
    with pytest.raises(OptionError) as info:
        LinearMPC(robot, bounds=Bounds(u_min=0.0), u_max=1.0, horizn=5, weights={"R": 1})
    text = str(info.value)
    assert "u_max is given both as a keyword and in bounds=" in text
    assert "unknown keyword horizn" in text
    assert "weights must be a Weights, found dict" in text
    with pytest.raises(OptionError, match="formulation applies to LinearMPC only"):
        NonlinearMPC(tendon_sparse_map(), solver=Solver(formulation="sparse"))
    with pytest.raises(OptionError, match="unknown keyword formulation"):
        NonlinearMPC(tendon_sparse_map(), formulation="sparse")


def test_option_values_are_checked_against_the_model(robot):
    with pytest.raises(OptionError) as info:
        LinearMPC(
            robot,
            bounds=Bounds(u_min=[1.0, 2.0], u_max=0.0),
            estimator=Estimator(disturbance="state"),
            solver=Solver(name="gurobi"),
        )
    text = str(info.value)
    assert (
        "u_min" in text and "disturbance must be one of" in text and "solver must be one of" in text
    )
