"""diagnose on a system that is not the robot: a 1-DOF oscillator with one hidden effect.

tendonkit is meant for other plants, signal names, magnitudes and sample times too.  The system
is a mass-spring-damper (1 Hz, damping ratio 0.05), driven by a band-limited random force
(`force`, 2nd-order Butterworth at 2 Hz, rms 10) and measured as a position (`pos`, 2 % white
noise on the output), simulated with RK4 at 10 sub-steps per sample and a zero-order-held input.
Each effect is hidden at a fixed, clearly visible magnitude; training and validation are two
records each with different seeds.  The baseline is diagnose's default (`arx`, ARX(8, 8, 1)),
as a user would run it, at two sample times: 0.05 s (20 samples per period) and 0.01 s (100
per period, where equation-error ARX is biased by the output noise and diagnose falls back to
N4SID when it is grossly so, see docs/diagnose.md).  The plain linear system must give `none`.
The hysteresis is a Bouc-Wen spring of exponent 2 in parallel: the effect tries exponent 1.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from scipy.signal import butter, lfilter

from tendonkit.cli.diagnose import render_diagnosis
from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import diagnose
from tendonkit.simulate import play_operator

pytestmark = pytest.mark.slow

M, C, K = 1.0, 0.6, 40.0
#: Hidden effect -> parameters (forces in the units of `force`, angles/positions in rad).
EFFECTS = {
    "none": {},
    "coulomb_friction": {"Fc": 1.0},
    "backlash": {"b": 0.02},
    "input_delay": {"seconds": 0.05},
    "dead_zone": {"th": 3.0},
    "saturation": {"s": 12.0},
    "actuator_lag": {"tau": 0.1},
    "nonlinear_stiffness": {"k3": 100.0},
    "gravity": {"g": 10.0, "th0": 0.3},
    # a hysteretic spring in parallel (Bouc-Wen of exponent 2, which the effect does not
    # use: it tries exponent 1 and plays); yield at 0.2 (the position's std is about 0.3)
    "hysteresis": {"kh": 40.0, "zy": 0.2, "beta": 0.5, "gamma": 0.5},
}
#: Draws that miss, with the reason (docs/diagnose.md, "A system that is not the robot").
MISSES = {
    ("input_delay", 0.05): "one sample of delay is inside ARX(8, 8, 1)'s numerator (lags 1-8): "
    "not an error of that model",
    ("nonlinear_stiffness", 0.01): "the cubic dominates: the automatic ARX(3, 3, 0) fits the "
    "validation data 18.5 % (N4SID 8.8 % on training), and the stiffness terms fitted by "
    "equation error lose 7.7 points of its training simulation, so nothing is named (measured "
    "2026-11-26; an earlier record had backlash named)",
}


def _force(n: int, dt: float, seed: int, rms: float = 10.0, band: float = 2.0) -> np.ndarray:
    u = lfilter(*butter(2, band, fs=1.0 / dt), np.random.default_rng(seed).standard_normal(n))
    return rms * u / u.std()


def _response(
    u: np.ndarray,
    dt: float,
    effect: str,
    p: dict,
    sub: int = 10,
    mck: tuple[float, float, float] = (M, C, K),
) -> np.ndarray:
    m, c, k = mck
    if effect == "input_delay":
        d = round(p["seconds"] / dt)
        u = np.concatenate([np.full(d, u[0]), u[:-d]])
    elif effect == "dead_zone":
        u = np.sign(u) * np.maximum(np.abs(u) - p["th"], 0.0)
    elif effect == "saturation":
        u = np.clip(u, -p["s"], p["s"])
    elif effect == "actuator_lag":
        a = np.exp(-dt / p["tau"])
        u = lfilter([0.0, 1.0 - a], [1.0, -a], u)

    code = _CODES.get(effect, 0)
    args = (p.get("Fc", 0.0), p.get("k3", 0.0), p.get("g", 0.0), p.get("th0", 0.0))
    hyst = (p.get("kh", 0.0), p.get("beta", 0.0), p.get("gamma", 0.0), p.get("zy", 1.0))
    y = _rk4(np.asarray(u, dtype=float), dt, sub, m, c, k, code, *args, *hyst)
    return play_operator(y, p["b"]) if effect == "backlash" else y


#: The effects that act inside the dynamics, as codes for the compiled integrator.
_CODES = {"coulomb_friction": 1, "nonlinear_stiffness": 2, "gravity": 3, "hysteresis": 4}


@njit(cache=True)
def _acc(x, v, f, z, m, c, k, code, Fc, k3, g, th0, kh):  # pragma: no cover - numba
    force = f - c * v - k * x
    if code == 1:
        force -= Fc * np.tanh(v / 1e-3)
    elif code == 2:
        force -= k3 * x**3
    elif code == 3:
        force -= g * np.sin(x + th0)
    elif code == 4:
        force -= kh * z
    return force / m


@njit(cache=True)
def _dz(v, z, code, beta, gamma, zy):  # pragma: no cover - numba
    if code != 4:  # Bouc-Wen, exponent 2
        return 0.0
    return v - (beta * abs(v) * z * abs(z) + gamma * v * z * z) / zy**2


@njit(cache=True)
def _rk4(u, dt, sub, m, c, k, code, Fc, k3, g, th0, kh, beta, gamma, zy):  # pragma: no cover
    """Classical RK4 at ``sub`` steps per sample, the input held (compiled: the suite makes
    about a hundred records of 4000 samples)."""
    h = dt / sub
    x = v = z = 0.0
    y = np.empty(len(u))
    a = (m, c, k, code, Fc, k3, g, th0, kh)
    for i in range(len(u)):
        f = u[i]
        y[i] = x
        for _ in range(sub):
            k1x, k1v, k1z = v, _acc(x, v, f, z, *a), _dz(v, z, code, beta, gamma, zy)
            x2, v2, z2 = x + h / 2 * k1x, v + h / 2 * k1v, z + h / 2 * k1z
            k2x, k2v, k2z = v2, _acc(x2, v2, f, z2, *a), _dz(v2, z2, code, beta, gamma, zy)
            x3, v3, z3 = x + h / 2 * k2x, v + h / 2 * k2v, z + h / 2 * k2z
            k3x, k3v, k3z = v3, _acc(x3, v3, f, z3, *a), _dz(v3, z3, code, beta, gamma, zy)
            x4, v4, z4 = x + h * k3x, v + h * k3v, z + h * k3z
            k4x, k4v, k4z = v4, _acc(x4, v4, f, z4, *a), _dz(v4, z4, code, beta, gamma, zy)
            x += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
            v += h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
            z += h / 6 * (k1z + 2 * k2z + 2 * k3z + k4z)
    return y


def _data(effect: str, dt: float, seed: int, n: int = 4000) -> Dataset:
    exps = []
    for i in range(2):
        u = _force(n, dt, 10 * seed + i)
        y = _response(u, dt, effect, EFFECTS[effect])
        y = y + 0.02 * y.std() * np.random.default_rng(10 * seed + i + 5).standard_normal(n)
        exps.append(Experiment(t=dt * np.arange(n), u=u[:, None], y=y[:, None], name=f"r{i}"))
    return Dataset(inputs=("force",), outputs=("pos",), experiments=tuple(exps), dt=dt)


def _cases() -> list:
    out = []
    for dt in (0.05, 0.01):
        for effect in EFFECTS:
            reason = MISSES.get((effect, dt))
            marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
            out.append(pytest.param(effect, dt, marks=marks, id=f"{effect}-{dt}"))
    return out


@pytest.mark.parametrize(("effect", "dt"), _cases())
def test_the_hidden_effect_is_named(effect, dt):
    d = diagnose(_data(effect, dt, 1), _data(effect, dt, 2))
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"{effect} dt {dt}: causes {d.causes} via {d.baseline_method}; {top}")
    assert d.cause == effect, top
    if effect != "none":
        assert d.best is not None and d.best.gain > 0
    # One hidden effect, one cause: the sequence ends after it (a later step's stand-in is
    # not confirmed once refined: gravity at 0.05 s -> hysteresis +0.34, p = 0.12; hysteresis
    # at 0.01 s -> a Wiener curve +1.36, p = 1.0; docs/diagnose.md, step 8)
    assert d.causes == (effect,), [(s.cause, s.gain, s.stop) for s in d.steps]
    if (effect, dt) == ("hysteresis", 0.05):
        # The effect fits a Bouc-Wen operator of exponent 1 to a spring of exponent 2; friction
        # by the sign of the velocity reshapes the loop (+1.0 before the rule) and is left out
        # of friction's choice at the second step, which keeps its play in force space (another
        # path): the single cause ends after one step (docs/diagnose.md, step 8).
        assert d.causes == ("hysteresis",)
        friction = next(f for f in d.steps[1].findings if f.effect == "coulomb_friction")
        assert friction.params["structure"] == "play in force space"


@pytest.mark.parametrize(("effect", "dt"), [("saturation", 0.05), ("gravity", 0.05)])
def test_a_later_cause_that_refinement_removes_is_not_named(effect, dt):
    """Seeds 3 and 4 (not the calibration's): one hidden effect, named at step 1.  Step 2 then
    finds a stand-in significant as tested (a Wiener curve +0.93 after the input clip, a
    hysteresis +0.74 after gravity, both by equation error), which made up for the least-squares
    fit of step 1's structure: once both are refined, the stand-in's model simulates the
    validation data no better (p = 0.12 and 0.2 before this check).  The sequence ends after one
    cause and says why (docs/diagnose.md, step 8, "A later step is confirmed once refined")."""
    d = diagnose(_data(effect, dt, 3), _data(effect, dt, 4))
    print(f"{effect} dt {dt} seeds 3/4: causes {d.causes}; {[s.stop for s in d.steps]}")
    assert d.causes == (effect,)
    last = d.steps[1]
    assert last.cause == "none" and last.confirmation is not None
    assert last.confirmation["applied"] and last.confirmation["p_value"] >= 0.05
    assert any(f.significant for f in last.findings)
    assert "is not confirmed: the model it hands on simulates" in last.stop
    assert last.stop in render_diagnosis(d.to_dict())


# -- a second oscillator, which no effect was designed on ----------------------------------------

#: 0.4 Hz, damping ratio 0.2, mass 2; forces of rms 0.05 (band 0.8 Hz); 5 % output noise, at
#: dt 0.02 s (125 samples per period).  There ARX(8, 8, 1)'s training error is 2.7-4.4 times
#: N4SID's, and the extensions of that biased baseline named friction for a saturation and an
#: actuator lag (docs/diagnose.md, "A held-out oscillator").
M2, WN2, ZETA2, RMS2 = 2.0, 2 * np.pi * 0.4, 0.2, 0.05
MCK2 = (M2, 2 * ZETA2 * WN2 * M2, M2 * WN2**2)
XS2 = RMS2 / MCK2[2]  # static deflection under the rms force
EFFECTS2 = {
    "none": {},
    "backlash": {"b": 0.6 * XS2},
    "saturation": {"s": 1.1 * RMS2},
    "actuator_lag": {"tau": 0.3},
}


def _data2(effect: str, seed: int, n: int = 4000, dt: float = 0.02) -> Dataset:
    exps = []
    for i in range(2):
        u = _force(n, dt, 10 * seed + i, rms=RMS2, band=0.8)
        y = _response(u, dt, effect, EFFECTS2[effect], mck=MCK2)
        y = y + 0.05 * y.std() * np.random.default_rng(10 * seed + i + 5).standard_normal(n)
        exps.append(Experiment(t=dt * np.arange(n), u=u[:, None], y=y[:, None], name=f"r{i}"))
    return Dataset(inputs=("torque_cmd",), outputs=("angle_meas",), experiments=tuple(exps), dt=dt)


@pytest.mark.parametrize("effect", list(EFFECTS2))
def test_a_moderately_biased_baseline_falls_back_and_the_effect_is_named(effect):
    # The fallback of a *given* ARX(8, 8, 1) (diagnose's default before the baseline chose
    # its own structure): its bias ratios are what this oscillator was built to sit at.
    d = diagnose(_data2(effect, 1), _data2(effect, 51), method="arx")
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    check = d.baseline_check
    print(
        f"{effect} (2nd oscillator): cause {d.cause} via {d.baseline_method}, ratio "
        f"{check['error_ratio']:.2f}; {top}"
    )
    assert d.cause == effect, top
    if effect != "none":
        assert 2.5 < check["error_ratio"] < 4.0 and d.baseline_method == "n4sid"
        assert d.best is not None and d.best.gain > 5


# -- a sensor that clips: the saturation is seen in the data -------------------------------------


def _clipped(dt: float, seed: int, hi: float, lo: float, n: int = 4000) -> Dataset:
    """The first oscillator (no effect, 2 % noise) read by a sensor whose range is [lo, hi]."""
    data = _data("none", dt, seed, n)
    exps = [Experiment(t=e.t, u=e.u, y=np.clip(e.y, lo, hi), name=e.name) for e in data.experiments]
    return data.with_experiments(exps)


@pytest.mark.parametrize("dt", [0.05, 0.01])
@pytest.mark.parametrize("ends", ["upper", "both"])
def test_a_sensor_range_is_a_saturation_seen_in_the_data(dt, ends):
    """The output is clipped at the 97.5 % quantile of the training response (and at the 2.5 %
    one): ~2.5 % of the samples at each clipped end.  Where the chosen clip keeps the
    baseline's dynamics, the validation output's pile-up at the level is tested too, which
    names the cause where the fit gain alone is not significant (docs/diagnose.md)."""
    y = np.concatenate([e.y[:, 0] for e in _data("none", dt, 1).experiments])
    hi = float(np.quantile(y, 0.975))
    lo = float(np.quantile(y, 0.025)) if ends == "both" else -np.inf
    d = diagnose(_clipped(dt, 1, hi, lo), _clipped(dt, 2, hi, lo))
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    assert d.cause == "saturation", top
    best = d.best
    assert best is not None and best.gain > 2 and best.params["where"] == "output"
    assert best.params["upper"] == pytest.approx(hi)
    assert (best.params["lower"] is None) == (ends == "upper")
    direct = best.test.get("direct")
    # Where the clip is added to the baseline's dynamics (not re-identified), the pile-up at
    # the level is tested.  At dt 0.01 the baseline is the N4SID fallback refined by its
    # simulation error, and the extension is refined too before it is scored: with both ends
    # clipped its fit gain is significant on its own as well (before both were refined it
    # was not, p > 0.01, and the pile-up named the cause alone).
    # the pile-up is tested exactly where the clip keeps the baseline's dynamics
    assert (direct is None) == bool(best.params["refit_unclipped"]), best.params
    assert direct is None or direct["p_value"] < 1e-10
    if (dt, ends) == (0.01, "both"):
        assert direct is not None and best.test["loss_p_value"] < 1e-3


def _two_tanks(seed: int, n: int = 1500, dt: float = 4.0) -> Dataset:
    """Two tanks with Bernoulli outflows and no overflow, a step test of the pump over levels
    2, 3, 5 and 6 held 150-300 samples each, the lower level read by a noise-free 12-bit
    sensor: every rest repeats one value, the highest the most (a case from review)."""
    rng = np.random.default_rng(seed)
    u = np.empty(n)
    i = 0
    while i < n:
        d = int(rng.integers(150, 300))
        u[i : i + d] = rng.choice([2.0, 3.0, 5.0, 6.0])
        i += d
    k1, k2, k3, k4 = 0.2, 0.2, 0.15, 0.1
    x1 = (k4 * u[0] / k1) ** 2
    x2 = (k2 * np.sqrt(x1) / k3) ** 2
    y = np.empty(n)
    h = dt / 20
    for j in range(n):
        y[j] = x2
        for _ in range(20):
            x1 += h * (-k1 * np.sqrt(max(x1, 0.0)) + k4 * u[j])
            x2 += h * (k2 * np.sqrt(max(x1, 0.0)) - k3 * np.sqrt(max(x2, 0.0)))
    q = 1.2 * y.max() / 2**12
    exp = Experiment(t=dt * np.arange(n), u=u[:, None], y=np.round(y / q)[:, None] * q, name="r")
    return Dataset(inputs=("pump",), outputs=("level",), experiments=(exp,), dt=dt)


def test_a_rest_at_the_top_of_a_step_test_is_not_a_clip():
    """The top rest piles up at one value like a clip, and a clip there gains +4.8 points (the
    √ outflow makes the linear model miss the highest level).  The inputs rest too, so the
    pile-up is not evidence of a saturation, and the gain alone is not significant."""
    d = diagnose(_two_tanks(3), _two_tanks(4), method="arx", options={"offset": True})
    sat = next(f for f in d.findings if f.effect == "saturation")
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    assert d.cause != "saturation", top
    assert sat.gain > 2 and sat.params["where"] == "output"  # the pile-up was found ...
    direct = sat.test.get("direct")  # ... and not taken for a clip
    assert direct is None or all(t["p_value"] == 1.0 for t in direct["tests"]), direct
    # re-identified dynamics: its gain is not the clip's, and the pile-up is not tested; the
    # clip added to the baseline's dynamics: tested, and not seen
    assert (direct is None) == bool(sat.params["refit_unclipped"]), sat.params
