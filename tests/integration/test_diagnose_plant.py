"""diagnose names the plant's hidden effect (issue 6), over several seeds and magnitudes.

For every effect, data are collected from the plant with that effect switched on at a
magnitude drawn at random (seeded) in its range (plant spec §10), with sensor noise on; the
nominal plant must give ``none``.  Training: one lap of circles at 2–12 cm plus 120 s of
pseudo-random motion; validation: a new pseudo-random seed (360 s) plus clockwise circles at
1.5, 6.5 and 11.5 cm (spec §12).

Baseline for every case: a *bilinear* ARX(3, 3, 1) (``bilinear=True``: products of every
input with every output).  ``diagnose`` answers "what does *this* model get wrong", so the
baseline must be adequate for the nominal plant and no richer.  The robot's joints stiffen
with the sum of the tensions (``q ≈ ρ ΔT / K(ΣT)``), which no linear model represents: the
linear ARX(3, 3, 1) fits the nominal plant at 85 %, the bilinear one at 95 %.  With the linear
baseline that structural error hid the effects behind it (second session: B named on 2 of 6
seeds, G on 4, Z and K softening on none); with the bilinear one the effects stand out.
na = nb = 3 is the smallest order whose nominal validation fit is within 0.5 points of
ARX(8, 8, 1) (a 2-DOF mechanical system: two modes, plus one lag for the zero-order hold); an
ARX(8, 8, 1) covers input lags 1–8 and so absorbs any delay up to about 5 frames.

``min_gain`` = 0.5 points (the default is 0.25).  With a baseline at 95 %, the nominal plant
keeps a systematic detail of how the frames sample tensions and angles: a one-sample lag or a
1¼-sample delay on the inputs gains +0.23 to +0.40 points, p_adj < 1e-4, on every nominal draw
(both protocols).  It is real structure, not noise, so no significance level removes it; the
floor of 0.5 points lies between it and the weakest hidden effects (D at 45 ms: +0.59).

Inputs: the measured tensions, except for effects D (actuation delay) and F (force-loop lag),
which act between the command and the applied tension.  The load cells read the applied
tension, so from measured forces both are invisible; the tests use the commanded tensions, as
the MPC does.

Protocols.  Every effect but Z uses the standard protocol (pretension 105 N for the circles,
70–130 N in the random motion).  **Z (dead zone, tendon slack) needs tensions that reach the
slack threshold**: above it the dead zone is ``T - T_dz``, an exact offset of every input that no
model can tell from a different pretension (checked: a threshold below every tension gives
``none``; the standard protocol reaches thresholds above ~30 N only on its largest moves).  Z therefore uses the *slack* protocol — circles at 50 N and random motion at
40–100 N — where the low tendon of a large move goes slack; the nominal plant is checked on
the slack protocol as well, so the suite shows that this protocol alone does not name a cause.

Detectable sub-ranges (the bottom of a range can be no effect at all):

- B: half-play b >= 7.5 mrad (1.5 σ_q).  A play below the 5 mrad camera noise is hidden in it.
- D: delay >= 1.5 frames (45 ms).  A delay below one frame is a fractional ZOH delay that the
  baseline's numerator represents exactly; 0 ms is no effect at all.
- F: carriage slew limit k_t·v_max <= 100 N/s (τ_f, v_max, k_t each drawn in range).  A fast
  carriage lets the force loop track the commands.
- G: the mounts that load the joints at rest (horiz_tilt, horiz_pan).  In the fast plant
  gravity is linearised (G0 + K_G q, spec §9); "up" and "down" have G0 = 0 and only change
  the linear stiffness, which a linear baseline identifies exactly.
- K: hardening k3 in [0.5, 5]; softening s in [0.2, 0.4] with q_s in [0.2, 0.4].
- Z: T_dz in [25, 40] N (w in [1, 5] N).  The commands never go below 20 N, so a threshold
  below ~25 N is hardly reached and one below 20 N is an offset everywhere.

Single draws that miss are listed in ``MISSES`` with the reason and marked as strict expected
failures (the suite fails the day one is named right, so the list stays true): over seeds
1–6 they are A and K hardening at the bottom of their ranges, where the extension's gain is
significant but below ``min_gain`` (0.5 points), and the weakest softening (s at the
bottom, q_s at the top of its range).  docs/diagnose.md has the calibration table.
"""

from __future__ import annotations

import functools
import time

import numpy as np
import pytest

from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import diagnose

pytestmark = pytest.mark.slow

#: Expected cause per plant effect (plant spec §10 id).
EXPECTED = {
    "nominal": "none",
    "A": "coulomb_friction",
    "B": "backlash",
    "D": "input_delay",
    "F": "actuator_lag",
    "G": "gravity",
    "K": "nonlinear_stiffness",
    "K_softening": "nonlinear_stiffness",
    "Z": "dead_zone",
    "nominal_slack": "none",
}
#: Protocol per case (module docstring): Z and its nominal control need slack tendons.
PROTOCOL = {"Z": "slack", "nominal_slack": "slack"}
SEEDS = (1, 2, 3, 4, 5, 6)
BASELINE = {"na": 3, "nb": 3, "nk": 1, "bilinear": True}
#: The single-effect suite measures the first step's naming (the calibration below): the
#: sequence of causes and the refinement are not run there (``test_two_effects_are_both_named``
#: runs them on plants with two effects).
FIRST_STEP = {"max_causes": 1, "refine": False}
#: Smallest gain that names a cause with this baseline (module docstring; default 0.25).
MIN_GAIN = 0.5


def draw(effect: str, seed: int) -> dict:
    """Plant parameters with ``effect`` on, at a magnitude drawn in its (detectable) range."""
    rng = np.random.default_rng(1000 + seed)

    def u(a: float, b: float) -> float:
        return float(rng.uniform(a, b))

    if effect in ("nominal", "nominal_slack"):
        return {}
    if effect == "A":
        mu_k = u(0.05, 0.3)
        return {
            "friction_on": True,
            "friction_mu_k": mu_k,
            "friction_mu_s": mu_k * u(1.1, 1.5),
            "friction_beta0": u(0.02, 0.15),
        }
    if effect == "B":
        return {"backlash_on": True, "backlash_b": u(0.0075, 0.02)}
    if effect == "D":
        return {"delay_on": True, "delay_s": u(0.045, 0.15)}
    if effect == "Z":
        return {"deadzone_on": True, "deadzone_T": u(25.0, 40.0), "deadzone_w": u(1.0, 5.0)}
    if effect == "F":
        tau = u(0.05, 0.5)
        while True:  # slew limit k_t·v_max <= 100 N/s (see the module docstring)
            vmax = u(0.001, 0.01)
            kt = float(np.exp(rng.uniform(np.log(5e3), np.log(1e5))))
            if kt * vmax <= 100.0:
                break
        return {"forcelag_on": True, "forcelag_tau": tau, "forcelag_vmax": vmax, "forcelag_kt": kt}
    if effect == "G":
        return {"mount": str(rng.choice(["horiz_tilt", "horiz_pan"]))}
    if effect == "K":
        return {"hardening_on": True, "hardening_k3": u(0.5, 5.0)}
    if effect == "K_softening":
        return {"softening_on": True, "softening_s": u(0.2, 0.4), "softening_qs": u(0.2, 0.4)}
    raise KeyError(effect)


@functools.cache
def circles(radii: tuple[float, ...], clockwise: bool = False, pretension: float | None = None):
    """The circles protocol, one lap (computed once per worker: every effect uses it)."""
    from tendonkit.robot.protocol import circles as make

    kw = {} if pretension is None else {"pretension": pretension}
    return make(laps=1, radii=list(radii), clockwise=clockwise, **kw)


@functools.cache
def pseudo_random(duration: float, seed: int, pretension_range: tuple | None = None):
    """The pseudo-random protocol (computed once per worker and seed)."""
    from tendonkit.robot.protocol import pseudo_random as make

    kw = {} if pretension_range is None else {"pretension_range": pretension_range}
    return make(duration=duration, seed=seed, **kw)


def plant_data(
    params: dict, seed: int, commanded: bool, protocol: str = "standard"
) -> tuple[Dataset, Dataset]:
    """Training and validation data from the plant (short protocol, noise on).

    ``protocol="slack"`` lowers the pretension (circles at 50 N, random motion at 40–100 N)
    so that the low tendon of a large move goes slack.
    """
    from tendonkit.fmu._config import PlantConfig
    from tendonkit.fmu.plant import Plant

    cfg = PlantConfig(noise_on=True, seed=seed, **params)
    inputs = ("u1", "u2", "u3", "u4") if commanded else ("T1", "T2", "T3", "T4")

    def dataset(parts: list) -> Dataset:
        exps = []
        for i, (name, proto) in enumerate(parts):
            plant = Plant(cfg.replace(seed=seed + i))
            plant.reset()
            log = plant.record(proto.u)
            u = log["u"] if commanded else log["T_meas"]
            exps.append(Experiment(t=log["t"], u=u, y=log["q"][:, :2], name=name))
        return Dataset(inputs=inputs, outputs=("q1", "q2"), experiments=tuple(exps), dt=0.03)

    slack = protocol == "slack"
    pretension = 50.0 if slack else None
    span = (40.0, 100.0) if slack else None
    train = dataset(
        [
            ("circles", circles((0.02, 0.04, 0.06, 0.08, 0.10, 0.12), pretension=pretension)),
            ("random", pseudo_random(120, seed, span)),
        ]
    )
    valid = dataset(
        [
            ("random", pseudo_random(360, seed + 1000, span)),
            ("circles", circles((0.015, 0.065, 0.115), True, pretension)),
        ]
    )
    return train, valid


def _run(effect: str, seed: int, protocol: str | None = None):
    params = draw(effect, seed)
    protocol = protocol or PROTOCOL.get(effect, "standard")
    train, valid = plant_data(params, seed, commanded=effect in ("D", "F"), protocol=protocol)
    t0 = time.perf_counter()
    d = diagnose(train, valid, method="arx", options=BASELINE, min_gain=MIN_GAIN, **FIRST_STEP)
    elapsed = time.perf_counter() - t0
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"{effect} seed {seed} {params}: cause {d.cause}; {top}; {elapsed:.1f} s")
    return d, top


#: Draws where diagnose names another cause or none (reported, not hidden; docs/diagnose.md).
MISSES = {
    ("A", 4): "mu_k 0.050, beta0 0.038 (bottom of both ranges): coulomb_friction +0.40 points, "
    "p_adj 1e-3 — significant, but below min_gain (0.5 points)",
    ("K", 4): "k3 0.50 (bottom of the range): nonlinear_stiffness +0.48 points, p_adj 1e-8 — "
    "significant, but below min_gain (0.5 points)",
    ("K_softening", 5): "s 0.22 (bottom) with q_s 0.39 (top): the softening torque "
    "s·K·(q - q_s·tanh(q/q_s)) ~ s·K·q³/(3 q_s²) is weakest there; nonlinear_stiffness +0.15",
}


def _cases() -> list:
    cases = []
    for effect in EXPECTED:
        for seed in SEEDS:
            reason = MISSES.get((effect, seed))
            marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
            cases.append(pytest.param(effect, seed, marks=marks, id=f"{effect}-{seed}"))
    return cases


#: The force loop of effect F (plant spec): each tendon's tension also follows the joint it
#: wraps, ``T = R + g·q`` with ``g = k_t · dL/dq`` — negative for the tendon that pulls the joint
#: positive (u1 on q1, u2 on q2), positive for its antagonist (u3, u4): ±244 N/rad at seed 1.
TENDON_LOAD = {"u1": ("q1", -1.0), "u2": ("q2", -1.0), "u3": ("q1", 1.0), "u4": ("q2", 1.0)}


@pytest.mark.parametrize(("effect", "seed"), _cases())
def test_diagnose_names_the_hidden_effect(effect, seed):
    d, top = _run(effect, seed)
    assert d.cause == EXPECTED[effect], top
    if d.cause != "none":
        assert d.best is not None and d.best.gain > 0
        assert d.best.p_adjusted < d.settings["alpha"]
    else:
        assert d.best is None
    if effect == "F":
        # found as what it is: a lag in a loop with the joints, each tendon that the search
        # links to its own joint with the sign of its stretch
        loop = d.best.params.get("loop", {})
        assert d.best.params.get("in_loop") and len(loop) == 4, d.best.params
        own = [(n, v["weight"]) for n, v in loop.items() if v["output"] == TENDON_LOAD[n][0]]
        assert len(own) >= 3 and all(np.sign(w) == TENDON_LOAD[n][1] for n, w in own), loop


def test_a_dead_zone_below_every_tension_names_no_cause():
    """A threshold below every tension (12 N, w 2 N; the commands stay >= 20 N) is an offset.

    Above the threshold the dead zone is ``T - T_dz`` on every input, which the baseline
    represents exactly: there is nothing to find, and diagnose must not invent a cause.
    (A threshold the standard protocol does reach is found: T_dz = 34 N gives dead_zone
    +0.75 points, p_adj 3e-5.)
    """
    params = {"deadzone_on": True, "deadzone_T": 12.0, "deadzone_w": 2.0}
    train, valid = plant_data(params, 1, commanded=False)
    d = diagnose(train, valid, method="arx", options=BASELINE, min_gain=MIN_GAIN, **FIRST_STEP)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    assert d.cause == "none", top


#: Plants with two hidden effects (seeds the single-effect calibration drew too): both must be
#: named, in any order, by the sequence of causes with the refinement on: gravity with an
#: actuation delay (G+D), tendon friction with gravity (A+G) and joint play with gravity
#: (B+G; on seed 2 a false friction is named first).  Friction with a force-controller lag
#: (A+F) is not named yet: the lag is (+34.1 points, p_adj 1e-10 on seed
#: 1, as a rate-limited lag in a loop with the joints), but behind it the friction effect gains
#: nothing significant (+0.1; docs/diagnose.md, "Two effects at once").
PAIRS = [
    (("G", "D"), 1),
    (("G", "D"), 2),
    (("A", "G"), 1),
    (("A", "G"), 2),
    # play + gravity: the load is seen behind the play since the terms added to a model with
    # output blocks are fitted on its own outputs (2026-11-27; before, every term extension
    # after the play lost 3-5 points and gravity was missed on both seeds)
    (("B", "G"), 1),
    (("B", "G"), 2),
]
#: The issue's own example, not met yet: a strict expected failure, so that the suite fails the
#: day it passes (the lag named, +34.1 with p_adj 1e-10 on seed 1; the friction not seen behind
#: it).
UNMET_PAIRS = {
    (("A", "F"), 1): "friction + force-controller lag: the lag is named in its loop with the "
    "joints, but the tendons' friction (a play of the tension after the force loop, of a width "
    "that grows with the tension) is not seen behind it: +0.1 points, not significant "
    "(docs/diagnose.md, 'Two effects at once')",
}


def _pair_cases() -> list:
    cases = [pytest.param(p, s, id=f"{p[0]}+{p[1]}-{s}") for p, s in PAIRS]
    for (p, s), reason in UNMET_PAIRS.items():
        mark = pytest.mark.xfail(strict=True, reason=reason)
        cases.append(pytest.param(p, s, marks=mark, id=f"{p[0]}+{p[1]}-{s}"))
    return cases


@pytest.mark.parametrize(("pair", "seed"), _pair_cases())
def test_two_effects_are_both_named(pair, seed):
    params = {**draw(pair[0], seed), **draw(pair[1], seed)}
    commanded = any(e in ("D", "F") for e in pair)
    train, valid = plant_data(params, seed, commanded=commanded)
    d = diagnose(train, valid, method="arx", options=BASELINE, min_gain=MIN_GAIN)
    chain = [(s.cause, round(s.gain, 2), s.p_adjusted) for s in d.steps]
    print(f"{'+'.join(pair)} seed {seed} {params}: causes {d.causes}; {chain}")
    assert {EXPECTED[pair[0]], EXPECTED[pair[1]]} <= set(d.causes), chain
    assert all(s.gain > 0 for s in d.steps if s.cause != "none")
    # the final step was refined, or refining was checked on held-out training data and
    # refused (it made the held-out part worse): either way the model says which
    notes = d.extended.provenance.notes
    assert (
        "refined by simulation error: normalised RMS" in notes
        or "not refined by simulation error: refined on the first 75% of the training" in notes
    ), notes
