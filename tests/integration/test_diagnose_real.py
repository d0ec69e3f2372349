"""diagnose on real benchmark data with the official splits (issue 6).

- EMPS (prismatic drive, known Coulomb friction) -> ``coulomb_friction``;
- Silverbox (electronic Duffing oscillator, cubic stiffness) -> ``nonlinear_stiffness``;
- Cascaded tanks (overflow, output clipped at 10 V) -> ``saturation``, seen in the data (the
  validation output piles up at the clip level) with a small gain.

Each must be named with a positive validation gain.  The baselines are the linear models of the
data READMEs: ARX(2, 2) for EMPS (its README's linear failure mode; a larger ARX of a pure
integrator in closed loop drifts), ARX(8, 8, 1) (tendonkit's default) for Silverbox, and for the
tanks ARX(8, 8, 1) with an offset: the tanks work around a non-zero level, so the benchmark's
best linear approximation is affine.  The fits are printed with the RMSE in the README's units
and convention, next to the published figures (run ``pytest -s`` to see them).
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest
from conftest import REAL_DATA

from tendonkit.cli.diagnose import render_diagnosis
from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import Diagnosis, diagnose
from tendonkit.diagnose.report import write_report
from tendonkit.simulate import simulate

pytestmark = [pytest.mark.slow, pytest.mark.first, pytest.mark.usefixtures("real_data")]


def _rmse(model, data: Dataset, skip: int) -> float:
    e = data.experiments[0]
    sim = simulate(model, e.u, y=e.y, initial="estimate")
    return float(np.sqrt(np.mean((e.y[skip:, 0] - sim[skip:, 0]) ** 2)))


def _report(name: str, d: Diagnosis, valid: Dataset, skip: int, unit: float, label: str) -> None:
    base = _rmse(d.baseline, valid, skip) * unit
    ext = _rmse(d.extended, valid, skip) * unit
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(
        f"\n{name}: cause {d.cause}; baseline fit {np.mean(list(d.baseline_fit.values())):.2f} %, "
        f"extended {np.mean(list(d.extended_fit.values())):.2f} %; test RMSE {base:.3g} -> "
        f"{ext:.3g} {label}; findings: {top}; margin {d.margin}"
    )


def _slice(path, start: int, stop: int, name: str) -> Dataset:
    full = Dataset.from_csv(path, ["u"], ["y"])
    e = full.experiments[0]
    s = slice(start, stop)
    exp = Experiment(t=e.t[s] - e.t[start], u=e.u[s], y=e.y[s], name=name)
    return full.with_experiments([exp])


def test_emps_is_coulomb_friction():
    root = REAL_DATA / "emps"
    train = Dataset.from_csv(root / "emps_train.csv", ["u_vir"], ["y_qm"])
    valid = Dataset.from_csv(root / "emps_test.csv", ["u_vir"], ["y_qm"])
    d = diagnose(train, valid, method="arx", options={"na": 2, "nb": 2, "nk": 1})
    # Published (README): linear black box fit ≈ 25 %; dynoNet 96.8 % (RMSE 2.6 mm); our
    # ARX(2, 2) free-run RMSE ≈ 24.7 mm.  RMSE here on y[20:] in mm, as the loader does.
    _report("EMPS", d, valid, 20, 1e3, "mm (published: linear ≈ 24.7, dynoNet 2.6)")
    assert d.cause == "coulomb_friction"
    assert d.best is not None and d.best.gain > 0


def test_silverbox_is_nonlinear_stiffness():
    path = REAL_DATA / "silverbox" / "silverbox_SNLS80mV.csv"
    train = _slice(path, 40650, 105712, "train")
    valid = _slice(path, 105712, 127400, "test_multisine")
    d = diagnose(train, valid)  # default options: the baseline chooses itself
    # Published (README): GRU/LSTM 1.5 mV, MLP-FIR 18.9 mV; ARX(2, 8) 7.13 mV and 1.77 mV
    # with one cubic regressor.  RMSE on y[50:] in mV.
    _report("Silverbox", d, valid, 50, 1e3, "mV (published: ARX 7.13, +cubic 1.77, LSTM 1.5)")
    assert d.cause == "nonlinear_stiffness"
    assert d.best is not None and d.best.gain > 0
    assert d.baseline_choice is not None and d.baseline_method == "arx"


def test_cascaded_tanks_is_saturation(tmp_path):
    root = REAL_DATA / "cascaded_tanks"
    train = Dataset.from_csv(root / "cascaded_tanks_train.csv", ["u"], ["y"])
    valid = Dataset.from_csv(root / "cascaded_tanks_test.csv", ["u"], ["y"])
    d = diagnose(train, valid, method="arx", options={"offset": True})
    # Published (README, full-record convention): BLA 0.75 V, NLSS2 0.34 V, grey box 0.18 V;
    # nonlinear_baselines ARX 0.685 V; our ARX(2, 4) 0.67 V.  RMSE on y[50:] in V (loader).
    _report(
        "Cascaded tanks", d, valid, 50, 1.0, "V (published: BLA 0.75, ARX 0.685, grey box 0.18)"
    )
    assert d.cause == "saturation"
    assert d.best is not None and d.best.gain > 0
    # Named because the validation output piles up at the clip level chosen on the training
    # data (37 samples at exactly 10 V, a smooth peak would put at most 4 there), not because
    # the gain is large: the loss route alone is not significant (docs/diagnose.md).
    assert d.best.params["where"] == "output" and d.best.params["upper"] == 10.0
    direct = d.best.test["direct"]
    assert direct["p_value"] < 1e-12 and direct["tests"][0]["count"] >= 30
    assert d.best.test["loss_p_value"] > 0.05
    # ... and the user is told both, and that a larger gain of another cause is unproven.
    text = render_diagnosis(d.to_dict())
    assert (
        "seen in the data: y: 37 samples at the upper clip level 10 while the model and the inputs move"
        in text
    )
    assert "the fit gain alone: p = 0." in text
    # A general static curve (here the Hammerstein or Wiener curve bending with the clip)
    # gains more; the clip, a special case of it, is what the data show.
    assert "static_nonlinearity gains more" in text and "special case" in text
    html = write_report(d, valid, tmp_path / "report").read_text()
    assert "Seen in the data" in html


# -- default options on every dataset (issue 18) -------------------------------------------------

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_real.py"


@functools.cache
def _bench():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("bench_real", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


@functools.cache
def _raw_cases():  # type: ignore[no-untyped-def]
    return _bench().cases()


@functools.cache
def _cases() -> dict[str, tuple[Dataset, Dataset]]:
    """Training and validation (the official test records) per dataset, from bench_real.py."""
    out = {}
    for name, train, tests in _raw_cases():
        exps = tuple(e for _, test, _ in tests[:1] + tests[1:2] * (name == "Coupled electric drives")
                     for e in test.experiments)  # fmt: skip
        out[name] = (train, train.with_experiments(list(exps)))
    return out


#: What the issue asks diagnose to name with default options (the official test records as
#: validation).
DEFAULTS = {"EMPS": "coulomb_friction", "Coupled electric drives": "static_nonlinearity"}


@pytest.mark.parametrize("name", list(DEFAULTS))
def test_default_options_name_the_known_effect(name):
    """``diagnose TRAIN VALID`` with no option, on the official split (the test record as
    validation)."""
    train, valid = _cases()[name]
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"\n{name} (defaults): causes {d.causes}; {top}")
    assert d.cause == DEFAULTS[name], top
    assert d.best is not None and d.best.gain > 0
    if name == "Coupled electric drives":
        # Two test records of 100 samples hold fewer than five batches of four autocorrelation
        # times: the rectifier's curve gains +24 points with p = 0.04 there, not significant at
        # alpha = 0.01 on its own.  The held-out blocks of the 2 x 400 training samples show it
        # (docs/diagnose.md, "Statistics").
        assert d.best.test["loss_p_value"] > 0.01
        assert d.best.test["held_out"]["p_value"] < 1e-3 and d.best.test["held_out"]["folds"] == 4
        assert d.best.params["structure"] == "Wiener"
        assert "shown on held-out blocks of the training data (4 folds, " in (
            render_diagnosis(d.to_dict())
        )
    if name == "EMPS":
        # A 3.75-sample input delay (one parameter) is significant too and gains 85 % of
        # friction's +31.9, and friction is named (before the third route of the test the
        # tie was with the delay, decided for friction by encompassing).
        delay = next(f for f in d.findings if f.effect == "input_delay")
        assert delay.significant and delay.gain >= d.settings["tie_ratio"] * d.best.gain
        enc = d.best.test["encompassing"]
        assert enc["over"] == "gravity" and not enc["encompasses"]
        assert max(enc["its_gain_after"], enc["gain_after_it"]) < d.settings["min_gain"]
        # The runner-up of the tie is a constant load (the drive's offset force, -3.16 N in
        # the benchmark's physical model), significant on the prediction over 124 samples
        # (since 2026-11-27): it explains the same drift as friction and neither adds to the
        # other, so the tie is reported with the experiment that tells them apart.
        assert d.ambiguous["between"] == ["coulomb_friction", "gravity"]
        assert not d.ambiguous["decided"]
        assert "neither accounts for the other" in d.ambiguous["statement"]
        assert "to tell them apart: " in render_diagnosis(d.to_dict())


def test_bouc_wen_is_hysteresis_at_benchmark_grade():
    """Default options on the Bouc-Wen benchmark: the hysteresis effect (a Bouc-Wen operator of
    the past output, carried by the simulation) is named first, and the extended model, refined
    by its simulation error, meets issue 18's target on the official multisine test (steady
    state, from the input alone): <= 5e-5 m (PNLSS 1.87e-5, dynoNet 4.52e-5; the linear
    baseline 1.55e-4)."""
    train, valid = _cases()["Bouc-Wen"]
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    bench = _bench()
    test = {n: (t, i) for n, t, i in next(c[2] for c in _raw_cases() if c[0] == "Bouc-Wen")}
    base, ext = (bench.rmse(m, *test["Bouc-Wen multisine"]) for m in (d.baseline, d.extended))
    print(f"\nBouc-Wen (defaults): causes {d.causes}; {top}; test RMSE {base:.3g} -> {ext:.3g} m")
    assert d.cause == "hysteresis", top
    assert d.best is not None and d.best.gain > 5 and d.best.params["structure"] == "bouc_wen"
    assert ext <= 5e-5 < base


def test_coupled_drives_rectifier_is_a_curve_after_the_dynamics():
    """Default options, the diagnosis inside the training records (bench_real's split: 300 +
    300 samples to fit, 100 + 100 to check, the official test records untouched): the
    sign-blind speed sensor is named ``static_nonlinearity`` as a Wiener structure — a cubic
    curve after the dynamics (a ``polynomial`` output block), refined with the linear part by
    simulation error — and the extended model meets issue 18's target on both official test
    records (<= 0.15; the baseline 0.26 / 0.33, published best linear 0.224 / 0.331)."""
    bench = _bench()
    _, train, tests = next(c for c in _raw_cases() if c[0] == "Coupled electric drives")
    fit_part, check = bench.split_training(train)
    d = diagnose(fit_part, check)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    ext = [bench.rmse(d.extended, t, i) for _, t, i in tests]
    base = [bench.rmse(d.baseline, t, i) for _, t, i in tests]
    print(f"\nCED (inside training): causes {d.causes}; {top}; test RMSE {base} -> {ext}")
    assert d.cause == "static_nonlinearity", top
    assert d.best is not None and d.best.params["structure"] == "Wiener"
    assert [b.kind for b in d.extended.output_blocks] == ["polynomial"]
    assert max(ext) <= 0.15 < min(base)


def test_cascaded_tanks_default_options_see_the_overflow():
    """Default options on the cascaded tanks (official split, the test record as validation):
    the training output piles up at 10 V (the overflow), so the saturation effect clips the
    output (not an input), and the test record's 37 samples at that level are seen directly —
    named although the clip's gain before refinement is below ``min_gain`` (a floor for effects
    inferred from the fit, not for one seen in the data)."""
    train, valid = _cases()["Cascaded tanks"]
    d = diagnose(train, valid)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"\nCascaded tanks (defaults): causes {d.causes}; {top}")
    assert d.cause == "saturation", top
    best = d.best
    assert best is not None and best.gain > 0 and best.params["where"] == "output"
    assert best.params["upper"] == 10.0 and best.test["direct"]["p_value"] < 1e-12
    test = {n: (t, i) for n, t, i in next(c[2] for c in _raw_cases() if c[0] == "Cascaded tanks")}
    base, ext = (_bench().rmse(m, *test["Cascaded tanks"]) for m in (d.baseline, d.extended))
    assert ext < 0.6 < base  # the refined clip: below the best linear model's 0.60 V


def test_wiener_hammerstein_curve_is_found_between_two_filters():
    """Default options but two causes at most (below) on the Wiener–Hammerstein benchmark, the
    diagnosis inside the training
    record (bench_real's split: 75 000 samples to fit, 25 000 to check): the circuit's diode
    curve is named ``static_nonlinearity`` with the curve *between* two filters — the first
    one split off the baseline's own poles and zeros as ``second_order_section`` input blocks —
    and the extended model, refined by simulation error with the filter, meets issue 18's
    target on the official test record: <= 5 mV (the linear baseline 43.9 mV; published
    block-structured 0.28 mV, dynoNet 1.2 mV).

    At most two causes: at default options the sequence names the curve and a delay and its
    third step names nothing (``benchmarks/bench_real.py --diagnose``: the same two causes and
    4.343 mV), and that step took 18 s of this test's 62 s on 75 000 samples; the stop
    itself is tested on every other sequence of the suite."""
    bench = _bench()
    _, train, tests = next(c for c in _raw_cases() if c[0] == "Wiener-Hammerstein")
    fit_part, check = bench.split_training(train)
    d = diagnose(fit_part, check, max_causes=2)
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    _, test, init = tests[0]
    base, ext = (bench.rmse(m, test, init) for m in (d.baseline, d.extended))
    print(f"\nWiener-Hammerstein (inside training): causes {d.causes}; {top}; test RMSE "
          f"{base * 1e3:.3g} -> {ext * 1e3:.3g} mV")  # fmt: skip
    assert d.cause == "static_nonlinearity", top
    assert d.causes == ("static_nonlinearity", "input_delay"), d.causes
    assert d.best is not None and d.best.params["structure"] == "Wiener-Hammerstein"
    assert "between two filters" in d.best.params["curve"]
    assert "second_order_section" in [b.kind for b in d.extended.input_blocks]
    assert ext <= 5e-3 < 40e-3 < base
