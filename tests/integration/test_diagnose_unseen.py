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
curve is named as one cause.  A third, a two-inertia drive at 2 ms with both angles measured
(:func:`two_inertia`), written after the effects *between two bodies* were built, checks that a
gap and a hardening in the coupling shaft are named, and nothing where there is neither.  A
fourth, a hydraulic cylinder at 2 ms (:func:`cylinder`), written as a probe after all of these,
checks that a dead time longer than the input-delay effect's whole-sample grid is named where
no linear model without it fits (on its probe, 15 of 18 single effects named:
docs/diagnose.md).

The score (named right / cases) is printed by ``pytest -s`` and recorded in docs/diagnose.md;
the cases that miss are listed in ``MISSES`` with what was named instead, as expected failures
(not strict: a miss that starts passing is reported, not hidden).
"""

from __future__ import annotations

from types import ModuleType

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from tendonkit.cli.diagnose import render_diagnosis
from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import diagnose
from tendonkit.diagnose.findings import evidence_notes

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
            marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
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


def two_inertia(effect: str, p: dict[str, float], seed: int, n: int = 5000) -> Dataset:
    """A third plant: a motor and a load coupled by a shaft, both angles measured at 2 ms.

    ``J1 θ1'' = τ − c1 θ1' − f``, ``J2 θ2'' = f − c2 θ2' − k2 θ2`` (a return spring on the load),
    the shaft's torque ``f = k12 d + c12 d'``, ``d = θ1 − θ2`` (J1 = 0.02, J2 = 0.05, k12 = 50,
    c12 = 0.05, c1 = 0.1, c2 = 0.2, k2 = 5: modes at 1.3 and 9.4 Hz); a band-limited torque
    (15 Hz, rms 1); 1 % white noise on both angles.  ``backlash``: a gap of half-width ``b`` in
    the shaft, ``k12·dead_zone(d, b)``; ``nonlinear_stiffness``: a hardening shaft,
    ``k12 (d + α d³)``; ``coulomb_friction``: a slipping clutch in the shaft, ``fc·sign(d')``;
    ``hysteresis``: a shaft whose half stiffness is a Bouc–Wen element,
    ``k12 (d/2 + h/2)``, ``dh = dd − β|dd|h − β·dd|h|`` (``h`` levels off at ``±1/(2β)``).
    """
    dt = 0.002
    rng = np.random.default_rng(seed)
    tau = lfilter(*butter(2, 15.0, fs=1 / dt), rng.standard_normal(n))
    tau = tau / tau.std()
    j1, j2, k12, c12, c1, c2, k2 = 0.02, 0.05, 50.0, 0.05, 0.1, 0.2, 5.0
    x = np.zeros(4)  # θ1, θ2, ω1, ω2
    hs = d_prev = 0.0
    y = np.empty((n, 2))
    sub = 10
    h = dt / sub
    for i in range(n):
        y[i] = x[:2]
        for _ in range(sub):
            d = x[0] - x[1]
            if effect == "backlash":
                d = np.sign(d) * max(abs(d) - p["b"], 0.0)
            f = k12 * d + c12 * (x[2] - x[3])
            if effect == "hysteresis":
                dd, d_prev = d - d_prev, d
                hs += dd - p["beta"] * (abs(dd) * hs + dd * abs(hs))
                f += k12 * (hs - d) / 2
            if effect == "coulomb_friction":
                f += p["fc"] * np.tanh((x[2] - x[3]) / 1e-3)
            if effect == "nonlinear_stiffness":
                f += k12 * p["alpha"] * d**3
            acc = ((tau[i] - c1 * x[2] - f) / j1, (f - c2 * x[3] - k2 * x[1]) / j2)
            x = x + h * np.array([x[2], x[3], *acc])
    y = y + 0.01 * y.std(axis=0) * np.random.default_rng(seed + 1).standard_normal(y.shape)
    e = Experiment(t=dt * np.arange(n), u=tau[:, None], y=y, name=f"two-inertia {seed}")
    return Dataset(inputs=("tau",), outputs=("theta_m", "theta_l"), experiments=(e,), dt=dt)


@pytest.mark.parametrize(
    ("effect", "seed"),
    [("none", 903), ("backlash", 903), ("nonlinear_stiffness", 904), ("coulomb_friction", 904),
     ("hysteresis", 903)],
)  # fmt: skip
def test_a_coupling_between_two_bodies_is_found(effect, seed, tmp_path):
    """Default options on the two-inertia drive: the gap, the hardening, the slip or the
    hysteresis of the shaft is named, as a function of the *difference* of the two measured
    angles (before the effects between two bodies, play and a hardening spring between two
    masses of a chain were missed 4 of 4, benchmarks/README.md); with none, nothing is
    named.  Backlash 904 and the hardening 903 pass too (measured 2026-11-26); they are left out
    for the suite's time."""
    rng = np.random.default_rng(seed)
    p = {
        "none": {},
        "backlash": {"b": float(rng.uniform(0.005, 0.015))},  # the shaft twists by ±0.04 rad rms
        "nonlinear_stiffness": {"alpha": float(rng.uniform(60.0, 200.0))},
        "coulomb_friction": {"fc": float(rng.uniform(0.05, 0.15))},  # torque rms 1
        "hysteresis": {"beta": float(rng.uniform(30.0, 60.0))},  # h levels off at 8-17 mrad
    }[effect]
    train, valid = two_inertia(effect, p, seed), two_inertia(effect, p, seed + 50)
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"\ntwo-inertia {effect} {p} seed {seed}: causes {d.causes}; {top}")
    assert d.causes == (effect,), top
    if effect != "none":
        assert d.best is not None and d.best.gain > 0
        between = d.best.params.get("between")
        assert between == "theta_m-theta_l", d.best.params
        # the extended model's term reads both angles: the coupling, not either body alone
        rep = d.extended.representation
        assert any(f.minus for t in rep.terms for f in t.factors)
        text = render_diagnosis(d.to_dict())
        assert f"extended ({d.best.effect} between theta_m-theta_l)" in text, text
        if effect == "backlash":  # the HTML report says it too
            from tendonkit.diagnose.report import write_report

            html = write_report(d, valid, tmp_path / "report").read_text()
            assert "Named cause: backlash between theta_m-theta_l" in html


def cylinder(delay: int, seed: int, n: int = 5000) -> Dataset:
    """A fourth plant: a valve-driven hydraulic cylinder with a load spring, its position
    measured at 2 ms (written 2026-11-27 as a probe of a plant no default was chosen on).

    The valve's spool follows the command with a 10 ms lag, ``0.01 x_v' = u(t − delay·dt) −
    x_v``; the chamber's pressure ``0.02 p' = x_v − A w − 0.05 p`` and the load
    ``0.05 w' = A p − 2 w − 40 y``, ``y' = w`` (``A = 1``); a command of random steps held
    16 ms, low-passed (Butterworth, 0.15 of Nyquist), rms 1; 1 % white noise on ``y``.
    """
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.standard_normal(n // 8 + 1), 8)[:n]
    u = lfilter(*butter(2, 0.15), u)
    u = u / u.std()
    v = np.concatenate([np.zeros(delay), u[: n - delay]])
    xv = pr = w = x = 0.0
    y = np.empty(n)
    sub = 10
    h = 0.002 / sub
    for i in range(n):
        y[i] = x
        for _ in range(sub):
            xv += h * (v[i] - xv) / 0.01
            pr += h * (xv - w - 0.05 * pr) / 0.02
            w += h * (pr - 2.0 * w - 40.0 * x) / 0.05
            x += h * w
    y = y + 0.01 * y.std() * np.random.default_rng(seed + 1).standard_normal(n)
    e = Experiment(t=0.002 * np.arange(n), u=u[:, None], y=y[:, None], name=f"cylinder {seed}")
    return Dataset(inputs=("valve",), outputs=("x",), experiments=(e,), dt=0.002)


def test_a_dead_time_no_linear_model_without_it_fits_is_named():
    """The cylinder above with a dead time of 10-20 samples, longer than the input-delay
    effect's whole-sample grid (11 on seed 961): every linear model *without* the dead time is
    poor (the automatic ARX without it simulated the validation data at −19 %, N4SID's
    automatic order at 7-40 %), so the ARX, 18.5 times N4SID's training error *behind* the
    dead time, was judged "not biased" against an N4SID that failed as well, and a lag was
    named first (+93 and +95 points, the delay second: seeds 961 and 962, and the probe's
    first two).
    The bias check now also identifies N4SID behind the dead times the baseline's choice
    found (``reference_behind_dead_times``): the ARX is biased, the fallback is N4SID of the
    order the dynamics need behind the dead time, and the delay is named (+19.3, the lag
    +14.9 the runner-up)."""
    from tendonkit.cli.diagnose import render_diagnosis
    from tendonkit.diagnose.engine import auto_baseline, check_baseline

    delay = int(np.random.default_rng(961).integers(10, 21))
    train, valid = cylinder(delay, 961), cylinder(delay, 1461)
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    summary = d.to_dict()
    check = summary["baseline"]["check"]
    print(f"\ncylinder dead time {delay}: causes {d.causes}; {top}; check {check}")
    behind = check["reference_behind_dead_times"]
    assert behind["decides"] and check["fallback"], check
    assert not check["error_ratio"] > check["threshold"]  # N4SID without it fails as well
    # the pinned N4SID stays the baseline after the pem check
    assert summary["baseline"]["method"] == "n4sid" and not check.get("pem", {}).get("fallback")
    # the fallback and the effects' candidates at the order N4SID has behind the dead time
    assert check["reference_options"]["order"] == behind["order"] >= 1
    assert d.causes[:1] == ("input_delay",), top
    assert d.best is not None and d.best.gain > 5.0
    # at one order the delay is clearly ahead of the lag (at N4SID's automatic order, each
    # candidate at its own, by 0.02-0.07 points)
    assert [f.effect for f in d.findings[:2]] == ["input_delay", "actuator_lag"], top
    assert d.findings[0].gain - d.findings[1].gain > 2.0, top
    text = render_diagnosis(summary)
    assert "behind the dead times found (valve 31 samples)" in text, text
    assert "against n4sid of order 1 without the dead times instead" in text, text
    # without dead times (none found, or zero samples) the check is the one it always was
    _, _, selected, _ = auto_baseline(train, {})
    plain = check_baseline(selected, train, "arx", {"valve": 0})
    assert plain is not None and "reference_behind_dead_times" not in plain
    assert not plain["biased"] and plain["error_ratio"] == check["error_ratio"]


def switched_on_at_rest(dead: int, seed: int, n: int) -> Dataset:
    """A second-order plant at rest whose input reaches it ``dead`` samples late, switched on
    with the record (nothing before it: how a generator written outside this repository
    commonly writes a dead time), random steps held 8 samples, 1 % noise (2026-11-28)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 8 + 1), 8)[:n]
    v = np.concatenate([np.zeros(dead), u])[:n]
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * v[k - 1] + 0.05 * v[k - 2]
    y += 0.01 * rng.standard_normal(n)
    e = Experiment(t=0.01 * np.arange(n), u=u[:, None], y=y[:, None], name=f"at rest {seed}")
    return Dataset(inputs=("u",), outputs=("y",), experiments=(e,), dt=0.01)


@pytest.mark.parametrize(("dead", "seed"), [(5, 1), (30, 2)])
def test_a_dead_time_switched_on_at_rest_is_the_only_cause(dead, seed):
    """The delayed model's inputs before the record were held at the first input: it
    simulated a step the plant never saw, and the 5-sample dead time was named
    ``static_nonlinearity`` (+22.3 against the delay's less), the 30-sample one
    ``input_delay`` then a false ``coulomb_friction`` (+4.6, p_adj 6e-16: the friction
    fitted that start).  They now start from the steady state at the measured start."""
    train, valid = switched_on_at_rest(dead, seed, 2000), switched_on_at_rest(dead, seed + 50, 1000)
    d = diagnose(train, valid)
    chain = [(s.cause, round(s.gain, 2)) for s in d.steps]
    assert d.causes == ("input_delay",), chain
    # the block adds to the baseline's own one-sample delay, and its numerator's first
    # coefficients can hold a few more samples (27.75 of 30 on seed 2)
    assert d.best is not None and dead - 3 <= d.best.params["samples"] <= dead, d.best.params
    assert d.extended_fit["y"] > 97.0, d.extended_fit


def drifting_integrator(seed: int) -> tuple[Dataset, Dataset]:
    """A pure integrator at 10 ms driven by a two-level input with a bias (its output ramps:
    0 -> 6.6 over the training record), 2 % white noise on the output; nothing hidden.
    Written as a probe (stop 48), outside every calibration."""
    rng = np.random.default_rng(seed)
    out = []
    for name, n in (("train", 2000), ("valid", 1000)):
        u = 0.3 + 0.5 * np.repeat(rng.choice([-1.0, 1.0], size=n // 20), 20)
        y = np.concatenate([[0.0], np.cumsum(u[:-1]) * 0.01])
        y = y + 0.02 * np.std(y) * rng.standard_normal(n)
        e = Experiment(t=np.arange(n) * 0.01, u=u[:, None], y=y[:, None], name=name)
        out.append(Dataset(inputs=("u",), outputs=("y",), experiments=(e,), dt=0.01))
    return out[0], out[1]


@pytest.mark.xfail(
    strict=True,
    raises=AssertionError,
    reason="a gain that only repairs the least-squares baseline's noise bias is named (not yet "
    "told apart; docs/diagnose.md, 'What the first step cannot tell from a biased baseline')",
)
def test_a_gain_that_only_repairs_the_baselines_least_squares_fit_names_no_cause():
    """ARX(6, 6) by least squares fits the validation record at 97.51 % (the noise allows 97.96),
    not biased enough for the N4SID check; a Bouc–Wen operator gains +0.38 (p_adj 1e-5) by
    closing part of that distance, and ``hysteresis`` is named.  The same ARX refined by its
    simulation error fits 97.86 %, the refined hysteresis model +0.03 over it.  Strict: the
    suite fails the day this false alarm is gone, so the list of misses stays true."""
    train, valid = drifting_integrator(11)
    d = diagnose(train, valid)
    assert d.cause == "none", [(f.effect, f.gain) for f in d.findings]


def _bench(name: str) -> ModuleType:
    """``benchmarks/<name>.py``, loaded from its file."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _tank_bench():  # type: ignore[no-untyped-def]
    """``benchmarks/bench_diagnose_chain.py`` (its two-tank plant, the chain, the SEA)."""
    return _bench("bench_diagnose_chain")


def test_an_effect_no_linear_model_follows_is_named_when_its_model_explains_the_data():
    """Two slow tanks (time constants 200 and 300 s at 1 s) fed by a pump slewing at 0.035 V/s
    (``bench_diagnose_chain.py --plant tanks --areas 20,30``, seed 822, one of the seeds the
    rule was built on): no linear baseline follows the pump — its validation fit is below zero, which
    alone names no cause — but the rate limit's model fits the validation data and closes
    most of the baseline's training misfit, so the lag is named and the result says why
    (docs/diagnose.md, step 6).  It was ``none`` before."""
    bench = _tank_bench()
    p = bench.draw("actuator_lag", 822, bench.TANK_RANGES)
    train = bench.tanks("actuator_lag", p, 822, (20.0, 30.0))
    valid = bench.tanks("actuator_lag", p, 1322, (20.0, 30.0))
    d = diagnose(train, valid, max_causes=1)
    assert d.cause == "actuator_lag" and d.unfit is None
    explains = d.best.test["explains"]
    assert explains["baseline_fit"] < 0 < 50 < explains["extended_fit"]
    assert explains["training_gain"] > 30 and explains["training_misfit"] < 40
    assert "the baseline alone does not explain" in render_diagnosis(d.to_dict())


@pytest.mark.parametrize(
    ("effect", "seed", "special", "as_tested"),
    [
        ("static_nonlinearity", 822, "dead_zone", []),
        ("saturation", 822, "saturation", ["static_nonlinearity"]),
    ],
)
def test_a_shape_contest_compares_the_models_handed_on(effect, seed, special, as_tested):
    """The fast tanks (``bench_diagnose_chain.py --plant tanks``, time constants 20 and 30 s):
    a general curve and its special shape are both significant, and the cause is named by
    their refined models (docs/diagnose.md, step 6).  A pump curve refined gains far more than
    a dead zone refined, and is named; a pump clipped at 5.9 V refined gains more than the
    curve — whose refined model simulates the validation data worse than as tested, so the
    curve enters the contest as tested — and the clip is named."""
    bench = _tank_bench()
    p = bench.draw(effect, seed, bench.TANK_RANGES)
    train = bench.tanks(effect, p, seed, (2.0, 3.0))
    valid = bench.tanks(effect, p, seed + 500, (2.0, 3.0))
    d = diagnose(train, valid, max_causes=1)
    assert d.cause == effect
    contest = d.best.test["contest"]
    assert contest["named"] == effect
    assert contest["between"] == ["static_nonlinearity", special]
    assert contest["kept_as_tested"] == as_tested
    # both significant on their own (the contest is between two significant findings)
    p_adj = {f.effect: f.p_adjusted for f in d.findings}
    assert p_adj["static_nonlinearity"] < 0.01 and p_adj[special] < 0.01
    gains = contest["refined_gains"]
    other = "static_nonlinearity" if effect == special else special
    assert gains[effect] > gains[other] + 0.25
    if as_tested:
        notes = " ".join(evidence_notes(d.to_dict()))
        assert "static_nonlinearity as tested: its refined model simulated" in notes


def test_a_pump_that_starts_at_a_voltage_is_a_dead_zone():
    """The fast tanks whose pump does nothing below 4-4.6 V and pumps in full above
    (``bench_diagnose_chain.py --plant tanks``, seed 822): a dead zone whose output jumps at
    the threshold.  No continuous zone has the jump, and a clip of the pump (+6.3 points) was
    named before the gate candidates; the gate is named, with its threshold near the truth."""
    bench = _tank_bench()
    p = bench.draw("dead_zone", 822, bench.TANK_RANGES)
    train = bench.tanks("dead_zone", p, 822, (2.0, 3.0))
    valid = bench.tanks("dead_zone", p, 1322, (2.0, 3.0))
    d = diagnose(train, valid, max_causes=1)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    assert d.cause == "dead_zone", top
    assert d.best.params["structure"] == "gate"
    assert abs(d.best.params["threshold"][0] - p["th"]) < 0.3, (d.best.params, p)
    gains = {f.effect: f.gain for f in d.findings}
    assert gains["dead_zone"] > gains["saturation"] + 3.0


def test_a_speed_limit_inside_a_force_loop_is_named_in_its_loop():
    """A series-elastic actuator whose motor's speed is limited (``bench_diagnose_chain.py
    --plant sea``, seed 901): the limit binds on the force loop's state, not on the command,
    so no lag or rate limit on the input shows (the gate of the loop's first route), but the
    loop's step limit itself removes most of the misfit (the second route, docs/diagnose.md:
    the table of effects).  Named ``saturation``, a static curve or friction before, on every
    seed of the bench."""
    _, train, valid = _tank_bench().sea_case("actuator_lag", 901)
    d = diagnose(train, valid)
    assert d.causes == ("actuator_lag",), [(f.effect, f.gain) for f in d.findings[:3]]
    params = d.best.params
    assert params["in_loop"] and params["loop_share"][0] > 1.0  # a spring stiffer than the load
    # the step limit earns the loop's gain: the same loop as a linear lag gains nothing
    assert params["step_limit_gain"] > 0.9 * d.best.test["train_gain"] > 5.0


def test_a_dead_band_on_a_finely_sampled_chain_shows_over_the_prediction_horizon():
    """The chain of three masses at 5 ms with a force dead band (``bench_diagnose_chain.py``,
    fresh seed 842, drawn after the horizon rule was written): the band gains +13.4 points,
    but the lightly damped chain's free-run error has an autocorrelation time of about 300
    samples (five batches) and a one-step prediction is mostly the 1 % measurement noise, so
    with those two routes it had p_adj 0.05 and nothing was named.  The third route, a
    prediction over 20 samples (4000 / 200), has fifty batches and the band is named."""
    bench = _tank_bench()
    p = bench.draw("dead_zone", 842)
    train, valid = bench.chain("dead_zone", p, 842), bench.chain("dead_zone", p, 1342)
    d = diagnose(train, valid, max_causes=1, refine=False)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    assert d.cause == "dead_zone", top
    test = d.best.test
    assert test["n_batches"] == 5 and test["p_value"] > 1e-3  # the free run
    assert test["prediction"]["p_value"] > 1e-3  # one step ahead
    ahead = test["horizon"]
    assert ahead["horizon"] == 20 and ahead["n_batches"] == 50 and ahead["p_value"] < 1e-10


def test_a_loop_that_gains_as_a_linear_lag_is_not_named():
    """The fast tanks with a pump curve (seed 801): after the curve, a loop with the load
    gained 2.2 training points, 2.0 of them without its step limit — linear dynamics the
    baseline's orders leave out, not an actuator's limit — and was named as a second cause
    (+1.1 points, p_adj 1e-3) while the first route's grid reached shares up to 8.  With its
    grid back at (1/4, 1/2, 1) that loop is no longer found; the rule that the step limit must
    earn half of the loop's gain, which refused it, is tested on its own in
    ``test_a_loop_is_used_where_its_step_limit_earns_the_gain`` (tests/core)."""
    bench = _tank_bench()
    p = bench.draw("static_nonlinearity", 801, bench.TANK_RANGES)
    train = bench.tanks("static_nonlinearity", p, 801, (2.0, 3.0))
    valid = bench.tanks("static_nonlinearity", p, 1301, (2.0, 3.0))
    d = diagnose(train, valid)
    assert d.causes == ("static_nonlinearity",), [(s.cause, s.gain) for s in d.steps]
    # the second step's lag is the lag on the input, not the loop its step limit did not earn
    lag = next(f for f in d.steps[1].findings if f.effect == "actuator_lag")
    assert not lag.params.get("in_loop"), lag.params


@pytest.mark.parametrize(("seed", "how"), [(157, "beyond"), (158, "refused")])
def test_a_linear_plant_with_slow_noise_names_no_curve_between_two_filters(seed, how):
    """A linear oscillator whose output noise is slow (AR 0.995; ``bench_diagnose_null.py
    --samples 2000,1000 --colour 0.995``, two of the seeds the rules were built on, not unseen
    like the servo's): the curve between two filters was named on 4 of 200 such plants,
    +0.7 … +3.1 points, on the one-step prediction route (p 1e-3 … 4e-21) — a gain of the
    first filter's *linear* memory, which the curve does not add to.  Now the curve must earn
    half of its training gain over that linear part, or the other structures are chosen (158:
    it earns 39 %); and where it does, the validation test must show the extension beating
    the linear part too (157: prediction p 4e-21 against the baseline, 1.0 against its linear
    part)."""
    bench = _bench("bench_diagnose_null")

    def data(first: int, n: int) -> Dataset:
        exps = tuple(bench.record(10 * seed + first + i, n, 0.3, 0.995) for i in range(2))
        return Dataset(inputs=("u",), outputs=("y",), experiments=exps, dt=1.0)

    d = diagnose(data(0, 2000), data(5, 1000))
    assert d.causes == ("none",), [(f.effect, f.gain, f.p_adjusted) for f in d.findings[:3]]
    curve = next(f for f in d.findings if f.effect == "static_nonlinearity")
    if how == "refused":
        refused = curve.params["between_refused"]
        assert refused["curve_train_gain"] < 0.5 * refused["train_gain"], refused
        assert not curve.params["curve"].endswith("between two filters")
    else:
        assert curve.params["curve"].endswith("between two filters")
        beyond = curve.test["linear_part"]
        assert curve.test["prediction"]["p_value"] < 1e-10 and beyond["prediction"] > 0.5
