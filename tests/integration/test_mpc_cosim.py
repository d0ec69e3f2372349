"""Co-simulation acceptance of issue 5: identified models tracked by both MPCs on the plant FMU.

For each plant — the nominal one and the "paper-like" preset (friction + force lag + 30 ms
delay + horizontal mounting + 2 Hz camera, plant spec §10), both with sensor noise (effect N,
σ_q = 5 mrad), because a feedback controller must live with it — the module collects training
data through the plant FMU with the paper's protocol (circles of 2–12 cm and 120 s of
pseudo-random motion, commanded forces u1..u4 -> measured q1, q2, :func:`tendonkit.robot.collect.collect`),
identifies an N4SID model (order 8, horizon 30) and a SINDYc model once (module-scoped fixture), and tracks
the petal ``r = A cos(3θ)``, A = 9 cm (spec §12) with

- the linear MPC on the N4SID model and the nonlinear MPC on the SINDYc model, with the tuned
  settings of :data:`tendonkit.robot.cosim.DEFAULTS`, and
- the open-loop kinematic controller of the data-collection protocol, on the same plant,
  reference and noise.

Which petal, and why.  The open-loop controller is the exact static inverse of the *nominal*
plant (it is built from the same parameters), so on the nominal plant its only error is the
dynamics: the lightly damped 3.6 / 4.7 Hz modes lag and ring behind the commands, an error
that grows with the square of the speed.  At the protocol's 2.5 cm/s that error is about
2 mrad RMS — below the 5 mrad sensor noise that any feedback controller feeds back — so there a
tie is all one can expect in principle (:func:`test_quasi_static_nominal_petal_leaves_nothing_to_win`
checks that premise).  The nominal case therefore uses a fast petal, 8 cm/s (2 laps, 20 s),
where the dynamics matter.  On the paper-like plant the open loop is wrong at any speed
(gravity sag of q2, friction hysteresis, lagging force loop), so it runs at the protocol's
2.5 cm/s (1 lap, 29 s).

Margins: required reduction of the RMS error of the plant's true joint angles over the whole
run, per joint (q1 / q2), against the reduction observed over 17 data seeds (0–16: training
data, sensor noise and identified models all change with the seed):

==========  ==========  ===========  =====================  ================================
plant       controller  required     observed, seeds 0–16   why this margin
==========  ==========  ===========  =====================  ================================
nominal     linear      35 / 30 %    45–59 / 41–64 %        ~10 points below the worst seed
nominal     SINDYc      30 / 50 %    42–54 / 62–74 %        ~12 points below the worst seed
paper-like  linear      10 / 45 %    19–49 / 55–78 %        N4SID quality varies most here
paper-like  SINDYc      30 / 65 %    41–52 / 77–81 %        ~11 points below the worst seed
==========  ==========  ===========  =====================  ================================

The worst of 17 seeds is about the 6th percentile, so a margin some 10 points below it keeps a
new seed from failing by chance while still demanding a clear win.  The margins are per
controller and plant because the spread is: 30 points for the linear MPC's q1 on the
paper-like plant, whose N4SID models from commanded forces under friction and force lag
differ most, under 23 points elsewhere.  This module uses seed 17, used neither for tuning
(:data:`tendonkit.robot.cosim.DEFAULTS`) nor for the table.  The nominal margins cannot be met by
removing a static offset (the open loop has none there): they need the model's dynamics.  On
the paper-like plant q2 gains most because the offset-free MPC removes the 69 mrad gravity sag
the open loop leaves.

Two lessons of the tuning, both for the linear MPC on the paper-like plant.  N4SID with its
default block-Hankel horizon of 10 samples (0.3 s) gave models whose MPC reduced the q1 error
by anywhere from 8 to 51 % across seeds; a horizon of 30 samples (0.9 s), which spans the
force loop's and the camera's slow dynamics, narrowed that to 19–49 % (the nominal plant
does not care).  And with a pair-sum weight of 1e-2 instead of 1 one seed fell to 6 % on q1:
its model had wrong common-mode gains (tension sum -> angle), which the optimiser exploited;
anchoring the pair sums at 2 P removes that direction.

Every closed-loop run must also respect the input bounds exactly (zero violations, the
master counts any attempt), and solve every QP (no fallback).  The last tests force solver
failures and check that the fallback is reported and the loop goes on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.dataset import Dataset
from tendonkit.fmu.build import build_plant_fmu
from tendonkit.fmu.plant import PlantConfig
from tendonkit.mpc import LinearMPC, Solver
from tendonkit.robot.collect import collect
from tendonkit.robot.cosim import (
    ControllerSettings,
    CosimResult,
    make_controller,
    make_reference,
    open_loop,
    run,
)
from tendonkit.robot.protocol import circles, pseudo_random

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("test_mpc_cosim")]

SEED = 17
#: Required reduction of the RMS true joint error against the open loop, per plant, controller
#: and joint
#: (module docstring: observed range and the reason for the gap).
MARGINS = {
    ("nominal", "linear"): (0.35, 0.30),
    ("nominal", "nonlinear"): (0.30, 0.50),
    ("paper_like", "linear"): (0.10, 0.45),
    ("paper_like", "nonlinear"): (0.30, 0.65),
}
#: Petal per plant: end-effector speed (m/s) and laps.
PETALS = {"nominal": (0.08, 2.0), "paper_like": (0.025, 1.0)}


@dataclass
class PlantCase:
    """One plant with its identified models, the petal and the open-loop run."""

    name: str
    fmu: Any
    models: dict[str, Any]
    reference: Any
    open_loop: CosimResult
    parameters: dict[str, Any]


def _training_data(fmu: Any) -> Dataset:
    parts = [
        circles(radii=[0.02, 0.04, 0.06, 0.08, 0.10, 0.12], laps=1),
        pseudo_random(120.0, seed=100 + SEED),
    ]
    recs = [collect(p, plant=fmu, seed=10 * SEED + i) for i, p in enumerate(parts)]
    sets = [r.to_dataset(inputs=("u1", "u2", "u3", "u4")) for r in recs]
    return Dataset(
        inputs=sets[0].inputs,
        outputs=sets[0].outputs,
        experiments=tuple(s.experiments[0] for s in sets),
        dt=0.03,
    )


@pytest.fixture(scope="session", params=["nominal", "paper_like"])
def plant(request, tmp_path_factory) -> PlantCase:
    name = request.param
    config = PlantConfig.preset(name).replace(noise_on=True)
    fmu = build_plant_fmu(tmp_path_factory.mktemp(name) / "plant.fmu", config)
    train = _training_data(fmu)
    models = {
        "linear": tk.identify(train, "n4sid", order=8, horizon=30),
        "nonlinear": tk.identify(train, "sindyc"),
    }
    speed, laps = PETALS[name]
    reference = make_reference("petal", amplitude=0.09, petals=3, speed=speed, laps=laps)
    parameters = {"seed": 1000 + SEED}  # the noise of the closed-loop runs
    baseline = open_loop(fmu, reference, parameters=parameters)
    return PlantCase(name, fmu, models, reference, baseline, parameters)


def _check_run(res: CosimResult) -> None:
    s = res.summary()
    assert s["input_bound_violations"] == 0
    assert np.all((res.u >= 20.0) & (res.u <= 190.0))
    assert s["fallbacks"] == 0, s["statuses"]
    assert len(res.u) == len(res.reference.t)


@pytest.mark.parametrize("kind", ["linear", "nonlinear"])
def test_mpc_beats_the_open_loop_controller(plant, kind):
    ctrl = make_controller(plant.models[kind])
    res = run(plant.fmu, plant.reference, ctrl, parameters=plant.parameters, name=kind)
    _check_run(res)
    mpc, ol = res.rms_error_true, plant.open_loop.rms_error_true
    required = np.array(MARGINS[plant.name, kind])
    reduction = 1.0 - mpc / ol
    report = (
        f"{plant.name} {kind}: MPC {1e3 * mpc.round(5)} mrad vs open loop "
        f"{1e3 * ol.round(5)} mrad; reduction {100 * reduction.round(3)} %, "
        f"required {100 * required} %"
    )
    print(report)
    assert np.all(reduction >= required), report
    # The camera sees the same win: the measured error (noise and camera lag included) is
    # lower too, so the gain is not an artefact of reading the plant's true angles.
    s, o = res.summary()["rms_error_rad"], plant.open_loop.summary()["rms_error_rad"]
    assert s["q1"] < o["q1"] and s["q2"] < o["q2"]


@pytest.mark.parametrize("plant", ["nominal"], indirect=True)
def test_quasi_static_nominal_petal_leaves_nothing_to_win(plant):
    """The premise of the fast nominal petal: at 2.5 cm/s the open loop is already at the
    noise level (RMS < 3 mrad against σ_q = 5 mrad), at 8 cm/s its error is twice as large."""
    slow = make_reference("petal", amplitude=0.09, petals=3, speed=0.025, laps=1.0)
    err_slow = open_loop(plant.fmu, slow).rms_error_true
    assert np.all(err_slow < 3e-3), err_slow
    assert np.all(plant.open_loop.rms_error_true > 2.0 * err_slow)


@pytest.mark.parametrize("plant", ["nominal"], indirect=True)
def test_forced_solver_failures_are_reported_and_the_loop_goes_on(plant):
    n = len(plant.reference.t)
    forced = set(range(200, 215)) | set(range(300, n, 50))
    ctrl = make_controller(plant.models["linear"], failure_hook=lambda k: k in forced)
    res = run(plant.fmu, plant.reference, ctrl, parameters=plant.parameters)
    s = res.summary()
    assert s["fallbacks"] == len(forced) == ctrl.n_fallbacks
    assert s["statuses"]["forced failure"] == len(forced)
    assert s["input_bound_violations"] == 0 and len(res.u) == n
    held = sorted(forced)
    np.testing.assert_array_equal(res.u[held], res.u[[k - 1 for k in held]])
    # The loop recovers: 1 s after the 0.45 s burst (single held steps go on) the error is
    # back below the open loop's on the same samples.
    after = slice(250, n)
    err = res.truth[after, :2] - plant.reference.q12[after]
    err_ol = plant.open_loop.truth[after, :2] - plant.reference.q12[after]
    rms, rms_ol = np.sqrt(np.mean(err**2, axis=0)), np.sqrt(np.mean(err_ol**2, axis=0))
    print(f"after the burst: MPC {1e3 * rms} mrad, open loop {1e3 * rms_ol} mrad")
    assert np.all(rms < rms_ol)


@pytest.mark.parametrize("plant", ["nominal"], indirect=True)
def test_a_failing_solver_holds_the_input(plant):
    """A genuine solver failure (Clarabel stopped after one iteration) on every step."""
    ref = make_reference("petal", speed=0.08, duration=3.0)
    ctrl = LinearMPC(plant.models["linear"], horizon=10, solver=Solver(options={"max_iter": 1}))
    res = run(plant.fmu, ref, ctrl, parameters=plant.parameters)
    s = res.summary()
    assert s["fallbacks"] == len(ref.t) and s["input_bound_violations"] == 0
    assert "MaxIterations" in s["statuses"]
    np.testing.assert_array_equal(res.u, np.repeat(ref.u_open_loop[:1], len(ref.t), axis=0))


@pytest.mark.parametrize("plant", ["paper_like"], indirect=True)
def test_design_path_gives_the_same_inputs(plant):
    """The cvxpy re-solve (design path) and the direct solver (fast path) agree in the loop."""
    ref = make_reference("petal", speed=0.025, duration=4.0)
    runs = [
        run(
            plant.fmu,
            ref,
            make_controller(plant.models[kind], ControllerSettings(fast=fast)),
            parameters=plant.parameters,
        )
        for kind in ("linear", "nonlinear")
        for fast in (True, False)
    ]
    # 1e-3 N: both paths hand the same QP to Clarabel; differences are solver round-off
    # amplified by the closed loop over 133 steps (observed < 1e-5 N)
    np.testing.assert_allclose(runs[0].u, runs[1].u, atol=1e-3)
    np.testing.assert_allclose(runs[2].u, runs[3].u, atol=1e-3)
