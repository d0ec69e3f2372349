"""diagnose names the plant's hidden effect (issue 6), over several seeds and magnitudes.

For every effect, data are collected from the plant with that effect switched on at a
magnitude drawn at random (seeded) in its range (plant spec §10), with sensor noise on; the
nominal plant must give ``none``.  Training: one lap of circles at 2–12 cm plus 120 s of
pseudo-random motion; validation: a new pseudo-random seed (360 s) plus clockwise circles at
1.5, 6.5 and 11.5 cm (spec §12).

Baseline for every case: ARX(3, 3, 1).  ``diagnose`` answers "what does *this* model get
wrong", so the baseline must be adequate for the nominal plant and no richer: na = nb = 3 is
the smallest order whose nominal validation fit is within 0.5 points of ARX(8, 8, 1) (a
2-DOF mechanical system: two modes, plus one lag for the zero-order hold).  An ARX(8, 8, 1)
covers input lags 1–8 and so absorbs any delay up to about 5 frames: a delay is then simply
not an error of that model, and no extension can gain.

Inputs: the measured tensions, except for effects D (actuation delay) and F (force-loop lag),
which act between the command and the applied tension.  The load cells read the applied
tension, so from measured forces both are invisible; the tests use the commanded tensions, as
the MPC does.

Detectable sub-ranges (the bottom of a range can be no effect at all):

- B: half-play b >= 7.5 mrad (1.5 σ_q).  A play below the 5 mrad camera noise is hidden in it
  (b = 5.4 mrad: best backlash gain −0.01 points).
- D: delay >= 1.5 frames (45 ms).  A delay below one frame is a fractional ZOH delay that the
  baseline's numerator represents exactly; 0 ms is no effect at all.
- F: carriage slew limit k_t·v_max <= 100 N/s (τ_f, v_max, k_t each drawn in range).  A fast
  carriage lets the force loop track the commands: τ_f = 0.22 s with 197 N/s left the baseline
  fit at 89.5 % (nominal 86–88 %).
- G: the mounts that load the joints at rest (horiz_tilt, horiz_pan).  In the fast plant
  gravity is linearised (G0 + K_G q, spec §9); "up" and "down" have G0 = 0 and only change
  the linear stiffness, which a linear baseline identifies exactly.
- K: hardening k3 in [0.5, 5]; softening is a known limit.

Known limits (``test_known_limits``, expected to fail, see docs/diagnose.md):

- Z (dead zone): with the true soft dead zone applied to the measured tensions, the re-identified
  baseline gains nothing on validation (oracle −0.1 to 0.0 points over 3 seeds).  The commanded
  tensions never go below 20 N and only 0.1–1 % of the samples reach the kink; the effect's
  footprint is the reduced pretension stiffness (Σ T_eff = S − 4 T_dz), which deepens the
  plant's own tension-dependent stiffness — a bilinear structure no static input block
  captures.  (Thresholds are drawn in [15, 40] N: below ~15 N the zone is never entered at all.)
- K softening (s in [0.2, 0.4]): the true shape, tanh(q/q_s) terms, gains at most +0.25 points.

Single draws that miss are listed in ``MISSES`` with the reason and marked xfail.  Seeds 1–3
alone would flatter some effects, so the suite runs seeds 1–6 (docs/diagnose.md, "Calibration
over six seeds"): B is named on 2 of 6 draws (input play, i.e. coulomb_friction, wins the
others), G on 4 of 6, A and K hardening on 5 of 6, D, F and the nominal plant on 6 of 6.
"""

from __future__ import annotations

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
}
#: Effects diagnose does not find with these protocols and a linear baseline (module docstring).
KNOWN_LIMITS = {"Z": "dead_zone", "K_softening": "nonlinear_stiffness"}
SEEDS = (1, 2, 3, 4, 5, 6)
BASELINE = {"na": 3, "nb": 3, "nk": 1}


def draw(effect: str, seed: int) -> dict:
    """Plant parameters with ``effect`` on, at a magnitude drawn in its (detectable) range."""
    rng = np.random.default_rng(1000 + seed)

    def u(a: float, b: float) -> float:
        return float(rng.uniform(a, b))

    if effect == "nominal":
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
        return {"deadzone_on": True, "deadzone_T": u(15.0, 40.0), "deadzone_w": u(1.0, 5.0)}
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


def plant_data(params: dict, seed: int, commanded: bool) -> tuple[Dataset, Dataset]:
    """Training and validation data from the plant (short protocol, noise on)."""
    from tendonkit.fmu._config import PlantConfig
    from tendonkit.fmu.plant import Plant
    from tendonkit.protocol import circles, pseudo_random

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

    train = dataset(
        [
            ("circles", circles(laps=1, radii=[0.02, 0.04, 0.06, 0.08, 0.10, 0.12])),
            ("random", pseudo_random(duration=120, seed=seed)),
        ]
    )
    valid = dataset(
        [
            ("random", pseudo_random(duration=360, seed=seed + 1000)),
            ("circles", circles(radii=[0.015, 0.065, 0.115], laps=1, clockwise=True)),
        ]
    )
    return train, valid


def _run(effect: str, seed: int):
    params = draw(effect, seed)
    train, valid = plant_data(params, seed, commanded=effect in ("D", "F"))
    t0 = time.perf_counter()
    d = diagnose(train, valid, method="arx", options=BASELINE)
    elapsed = time.perf_counter() - t0
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"{effect} seed {seed} {params}: cause {d.cause}; {top}; {elapsed:.1f} s")
    return d, top


#: Draws where diagnose names another cause or none (reported, not hidden; docs/diagnose.md).
MISSES = {
    ("A", 4): "mu_k 0.050, beta0 0.038 (bottom of both ranges): no finding above +0.25 points",
    ("B", 1): "backlash 15 mrad: input play (coulomb_friction) +1.88 beats output play +1.62; "
    "the tie is reported with the discriminating experiment",
    ("B", 4): "backlash 7.5 mrad (bottom of the tested range): input play +0.48, output play +0.29",
    ("B", 5): "backlash 8.5 mrad: input play +0.55 against output play +0.52 (a tie)",
    ("B", 6): "backlash 11.7 mrad: input play +1.93 beats output play +1.56",
    ("G", 4): "horiz_pan: asymmetric friction terms (tanh² of the velocity is ~1 while moving, a "
    "constant) +2.73 beat gravity +2.15 (p_adj 0.01)",
    ("G", 5): "horiz_tilt: gravity +0.97 points, p_adj = 0.2 (the sag follows the drifting "
    "pretension, so the gain varies from batch to batch)",
    ("K", 4): "k3 0.50 (bottom of the range): nonlinear_stiffness +0.63, p_adj 0.03",
}


def _cases() -> list:
    cases = []
    for effect in EXPECTED:
        for seed in SEEDS:
            reason = MISSES.get((effect, seed))
            marks = [pytest.mark.xfail(strict=False, reason=reason)] if reason else []
            cases.append(pytest.param(effect, seed, marks=marks, id=f"{effect}-{seed}"))
    return cases


@pytest.mark.parametrize(("effect", "seed"), _cases())
def test_diagnose_names_the_hidden_effect(effect, seed):
    d, top = _run(effect, seed)
    assert d.cause == EXPECTED[effect], top
    if d.cause != "none":
        assert d.best is not None and d.best.gain > 0
        assert d.best.p_adjusted < d.settings["alpha"]
    else:
        assert d.best is None


@pytest.mark.xfail(strict=False, reason="known limit, see the module docstring")
@pytest.mark.parametrize("effect", list(KNOWN_LIMITS))
def test_known_limits(effect):
    d, top = _run(effect, 1)
    assert d.cause == KNOWN_LIMITS[effect], top
