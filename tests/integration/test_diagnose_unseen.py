"""diagnose with default options on a plant it was never tuned on (issue 18): a case generator.

A DC servo measured by its **speed** (a tachometer), not a position: voltage ``u`` drives the
motor, ``tau_m dω/dt = K u_eff − ω − F(ω)``, ``tau_m = 0.15 s``, sampled at 10 ms with 2 % white
noise on the output; the input is a band-limited random voltage (rms 1 V) that crosses zero, so
the motor reverses.  The effects: Coulomb friction on the motor (so on a *speed* output), a dead
time of 10-20 samples, a dead zone and a saturation of the drive, a drive with a slew limit,
and a static torque curve ``u + c·u|u|``.  One hidden effect per case, its magnitude drawn in a range from the case's
seed.  The seeds (700 and up) and this plant were not used while any effect, threshold or default
was chosen; the cases are run as a user would, ``diagnose(train, valid)`` with no option.

A second plant, a Wiener–Hammerstein circuit at 1 ms (:func:`wiener_hammerstein`), written after
the curve-between-two-filters candidates were built (nothing was tuned on it), checks that its
curve is named as one cause.

The score (named right / cases) is printed by ``pytest -s`` and recorded in docs/diagnose.md;
the cases that miss are listed in ``MISSES`` with what was named instead, as expected failures
(not strict: a miss that starts passing is reported, not hidden).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from tendonkit.cli.diagnose import render_diagnosis
from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import diagnose

pytestmark = pytest.mark.slow

DT, TAU_M, GAIN = 0.01, 0.15, 1.0
EFFECTS = (
    "none",
    "coulomb_friction",
    "input_delay",
    "dead_zone",
    "saturation",
    "actuator_lag",
    "static_nonlinearity",
)
SEEDS = (701, 702)


def draw(effect: str, seed: int) -> dict[str, float]:
    """The effect's magnitude, drawn in its range from the seed."""
    rng = np.random.default_rng(seed)
    ranges = {
        "coulomb_friction": ("fc", 0.15, 0.35),  # friction torque, in volts of drive
        "input_delay": ("samples", 10, 20),  # dead time beyond the fine grid of 1-8
        "dead_zone": ("th", 0.2, 0.4),
        "saturation": ("limit", 0.9, 1.3),
        "actuator_lag": ("rate", 4.0, 8.0),  # slew limit, V/s (the input's rate is ~19 V/s rms)
        "static_nonlinearity": ("c", 0.3, 0.6),  # torque curve u + c u|u|
    }
    if effect == "none":
        return {}
    key, lo, hi = ranges[effect]
    value = float(rng.uniform(lo, hi))
    return {key: round(value) if key == "samples" else value}


def servo(effect: str, p: dict[str, float], seed: int, n: int = 6000) -> Dataset:
    """One record of the servo with ``effect`` hidden (parameters ``p``)."""
    rng = np.random.default_rng(seed)
    u = lfilter(*butter(2, 3.0, fs=1.0 / DT), rng.standard_normal(n))
    u = u / u.std()
    v = u.copy()
    if effect == "input_delay":
        d = int(p["samples"])
        v = np.concatenate([np.zeros(d), u[:-d]])
    elif effect == "dead_zone":
        v = np.sign(u) * np.maximum(np.abs(u) - p["th"], 0.0)
    elif effect == "saturation":
        v = np.clip(u, -p["limit"], p["limit"])
    elif effect == "actuator_lag":
        # a drive that follows its command through a 40 ms lag at a limited slew rate (a
        # linear lag alone is linear dynamics, which any baseline represents)
        a = np.exp(-DT / 0.04)
        step = p["rate"] * DT
        for k in range(1, n):
            v[k] = v[k - 1] + np.clip((1.0 - a) * (u[k] - v[k - 1]), -step, step)
    elif effect == "static_nonlinearity":
        v = u + p["c"] * u * np.abs(u)
    sub = 10
    h = DT / sub
    w = 0.0
    y = np.empty(n)
    for k in range(n):
        y[k] = w
        for _ in range(sub):
            friction = p["fc"] * np.tanh(w / 1e-3) if effect == "coulomb_friction" else 0.0
            w += h / TAU_M * (GAIN * v[k] - w - friction)
    y = y + 0.02 * y.std() * np.random.default_rng(seed + 1).standard_normal(n)
    exp = Experiment(t=DT * np.arange(n), u=u[:, None], y=y[:, None], name=f"servo{seed}")
    return Dataset(inputs=("volts",), outputs=("speed",), experiments=(exp,), dt=DT)


#: Cases that miss, with what diagnose named (docs/diagnose.md, "A plant never tuned on").
MISSES: dict[tuple[str, int], str] = {}


def _cases() -> list:
    out = []
    for effect in EFFECTS:
        for seed in SEEDS:
            reason = MISSES.get((effect, seed))
            marks = [pytest.mark.xfail(strict=False, reason=reason)] if reason else []
            out.append(pytest.param(effect, seed, marks=marks, id=f"{effect}-{seed}"))
    return out


@pytest.mark.parametrize(("effect", "seed"), _cases())
def test_a_servo_never_tuned_on(effect, seed):
    p = draw(effect, seed)
    d = diagnose(servo(effect, p, seed), servo(effect, p, seed + 50))
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"\nservo {effect} {p} seed {seed}: causes {d.causes}; {top}")
    assert d.cause == effect, top
    if effect != "none":
        assert d.best is not None and d.best.gain > 0


def test_a_static_curve_is_one_cause_however_it_is_shaped():
    """The torque curve ``u + c·u|u|`` is one memoryless curve on the input.  The polynomial
    that names it does not bend exactly like ``u|u|``, and a dead zone or a clip on the same
    input corrects the shape (+5 to +7 points on every seed before this rule): the sequence does
    not test them as a second cause, says so, and ends after one step."""
    p = draw("static_nonlinearity", 701)
    d = diagnose(servo("static_nonlinearity", p, 701), servo("static_nonlinearity", p, 751))
    assert d.causes == ("static_nonlinearity",)
    assert [s.cause for s in d.steps] == ["static_nonlinearity", "none"]
    reshaping = {
        s["effect"]: s["reason"] for s in d.steps[1].skipped if s["reason"].startswith("reshapes")
    }
    assert set(reshaping) == {"dead_zone", "saturation"}
    assert "static_nonlinearity named at step 1" in reshaping["dead_zone"]
    # a different cause is still tried at the second step
    assert {f.effect for f in d.steps[1].findings} >= {"coulomb_friction", "actuator_lag"}
    text = render_diagnosis(d.to_dict())
    assert (
        "not tested: dead_zone, saturation (reshapes the static_nonlinearity named at step 1"
        in (text)
    )


def wiener_hammerstein(seed: int, n: int = 8000) -> Dataset:
    """A second plant: a Wiener–Hammerstein circuit at 1 ms, unlike the benchmark's.

    Band-limited noise (a 4th-order Butterworth at 0.3 of Nyquist) drives a 2nd-order
    Chebyshev low-pass with 1 dB ripple (a resonant pole pair, cut-off 0.25), then a one-sided
    soft clip (a diode: ``0.6 tanh(x/0.6)`` for ``x > 0``, linear below), then a 2nd-order
    Butterworth low-pass at 0.15; 0.005 of white noise on the output.
    """
    from scipy.signal import cheby1

    rng = np.random.default_rng(seed)
    bu, au = butter(4, 0.3)
    u = lfilter(bu, au, rng.normal(size=n)) * 1.5
    b1, a1 = cheby1(2, 1.0, 0.25)
    x = lfilter(b1, a1, u)
    v = np.where(x > 0, 0.6 * np.tanh(x / 0.6), x)
    b2, a2 = butter(2, 0.15)
    y = lfilter(b2, a2, v) + 0.005 * rng.normal(size=n)
    return Dataset.from_arrays(u[:, None], y[:, None], dt=1e-3, inputs=["u"], outputs=["y"])


@pytest.mark.parametrize("seed", [901, 902])
def test_a_curve_between_two_filters_is_one_cause(seed):
    """Default options on the circuit above: one cause, ``static_nonlinearity``, with the curve
    between two filters (the first split off the baseline's dynamics), and nothing after it.
    Before the Wiener–Hammerstein candidates the curve was put on the raw input (+17 points)
    and a lag or a delay was named second to shape the first filter (on seeds 1-2 of this
    generator: validation fit 93.8 / 93.6 %)."""
    from tendonkit.metrics import fit
    from tendonkit.simulate import simulate

    train, valid = wiener_hammerstein(seed), wiener_hammerstein(seed + 50)
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    e = valid.experiments[0]
    before, after = (
        float(fit(e.y, simulate(m, e.u, y=e.y, initial="estimate"))[0])
        for m in (d.baseline, d.extended)
    )
    print(f"\nWiener-Hammerstein circuit seed {seed}: causes {d.causes}; {top}; "
          f"fit {before:.1f} -> {after:.1f} %")  # fmt: skip
    assert d.causes == ("static_nonlinearity",), top
    assert d.best is not None and d.best.params["structure"] == "Wiener-Hammerstein"
    assert "between two filters" in d.best.params["curve"]
    assert before < 80.0 and after > 97.0
