"""Tests of the SINDYc identifier: recovery of known maps, the threshold sweep, folding of the
normalisation, model files, options and the identifier contract."""

from __future__ import annotations

import re
import warnings
from collections.abc import Callable

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.dataset import Dataset, Experiment
from tendonkit.errors import DataError, OptionError, PluginError
from tendonkit.metrics import fit
from tendonkit.plugins import sindyc
from tendonkit.plugins.sindyc import SINDYc
from tendonkit.schema import Model, SparseMap
from tendonkit.simulate import simulate, simulate_dataset
from tendonkit.terms import CompiledTerms
from tendonkit.testing import identifier_checks

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_sindyc")

Step = Callable[[np.ndarray, np.ndarray], np.ndarray]


# -- known systems -------------------------------------------------------------------------------


def unit_step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """A stable map in unit-sized signals with x·u, x², sin(x) and linear input terms."""
    x1, x2 = x
    u1, u2 = u
    return np.array(
        [
            0.9 * x1 + 0.1 * x2 * u1 - 0.05 * x1**2,
            0.8 * x2 + 0.2 * u1 + 0.05 * np.sin(x1) - 0.1 * u2,
        ]
    )


#: The true terms of :func:`unit_step`, coefficients for (x1, x2).
UNIT_TERMS = {
    "x1": (0.9, 0.0),
    "x2*u1": (0.1, 0.0),
    "x1^2": (-0.05, 0.0),
    "x2": (0.0, 0.8),
    "u1": (0.0, 0.2),
    "sin(x1)": (0.0, 0.05),
    "u2": (0.0, -0.1),
}


def robot_step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """A polynomial map at the robot's scales: forces 20-190 N in, angles about 0.3 rad out."""
    x1, x2 = x
    u1, u2, u3, u4 = u
    return np.array(
        [
            0.03 + 0.9 * x1 + 1.6e-4 * (u1 - u2) + 2e-4 * x2 * u3 - 0.1 * x1**2,
            0.045 + 0.85 * x2 + 1.2e-4 * (u3 - u4) + 0.05 * x1 * x2 - 2e-7 * u4**2,
        ]
    )


def make_data(
    step: Step,
    *,
    seed: int,
    n: int,
    n_exp: int,
    u_range: tuple[float, float],
    x0: tuple[float, float],
    nu: int,
    names: tuple[tuple[str, ...], tuple[str, ...]],
) -> Dataset:
    """Noise-free experiments driven by random piecewise-constant inputs (held 3-19 samples)."""
    rng = np.random.default_rng(seed)
    exps = []
    for j in range(n_exp):
        hold = rng.integers(3, 20, size=n)
        u = np.repeat(rng.uniform(*u_range, size=(n, nu)), hold, axis=0)[:n]
        x = np.empty((n, 2))
        x[0] = np.asarray(x0) + 0.05 * rng.normal(size=2)
        for k in range(n - 1):
            x[k + 1] = step(x[k], u[k])
        exps.append(Experiment(t=0.03 * np.arange(n), u=u, y=x, name=f"exp{j}"))
    ds = Dataset(inputs=names[0], outputs=names[1], experiments=tuple(exps), dt=0.03)
    ds.validate()
    return ds


def unit_data(seed: int, n: int = 800, n_exp: int = 3) -> Dataset:
    return make_data(
        unit_step, seed=seed, n=n, n_exp=n_exp, u_range=(-1.5, 1.5), x0=(0.5, 0.0), nu=2,
        names=(("u1", "u2"), ("x1", "x2")),
    )  # fmt: skip


def robot_data(seed: int, n: int = 1500, n_exp: int = 2) -> Dataset:
    return make_data(
        robot_step, seed=seed, n=n, n_exp=n_exp, u_range=(20.0, 190.0), x0=(0.3, 0.3), nu=4,
        names=(("u1", "u2", "u3", "u4"), ("x1", "x2")),
    )  # fmt: skip


def coefficients_by_label(model: Model) -> dict[str, tuple[float, ...]]:
    rep = model.representation
    assert isinstance(rep, SparseMap)
    return {t.label: tuple(float(c) for c in row) for t, row in zip(rep.terms, rep.coefficients)}


def one_step(model: Model, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The model's map ``x[k+1] = Ξᵀ Θ(x[k], u[k])`` evaluated on rows of raw ``x`` and ``u``."""
    rep = model.representation
    assert isinstance(rep, SparseMap)
    ct = CompiledTerms(rep.terms)
    cols = {**dict(zip([s.name for s in model.states], x.T)), **dict(zip(model.input_names, u.T))}
    return np.asarray(
        ct.evaluate(np.array([cols[name] for name, _ in ct.keys])).T @ rep.coefficients
    )


def chosen_threshold(model: Model) -> float:
    match = re.match(r"threshold=([^ ]+) ", model.provenance.notes)
    assert match, model.provenance.notes
    return float(match.group(1))


@pytest.fixture(scope="session")
def unit_model() -> Model:
    return SINDYc(normalize=False).identify(unit_data(seed=1))


@pytest.fixture(scope="session")
def robot_model() -> Model:
    return SINDYc().identify(robot_data(seed=2))


# -- recovery ------------------------------------------------------------------------------------


def test_recovers_the_true_terms_and_coefficients(unit_model: Model) -> None:
    # Noise-free data and the true terms in the library: least squares on the selected terms is
    # exact up to rounding, so 1e-9 leaves a wide margin while any wrong term would show.
    got = coefficients_by_label(unit_model)
    assert set(got) == set(UNIT_TERMS)
    for label, true in UNIT_TERMS.items():
        np.testing.assert_allclose(got[label], true, rtol=0, atol=1e-9, err_msg=label)
    fresh = unit_data(seed=11, n_exp=2)
    for e in fresh.experiments:
        assert np.all(fit(e.y, simulate(unit_model, e.u, y=e.y)) > 99.9)


def test_recovers_a_polynomial_map_at_robot_scales(robot_model: Model) -> None:
    # With normalisation the terms are polynomials of (s - mean) * scale; the map they make in
    # raw units must be the true one.  Compared by evaluation at fresh points of the operating
    # range; the angles are ~0.3 rad, and 1e-9 rad is far below any missing or extra term.
    rep = robot_model.representation
    assert isinstance(rep, SparseMap)
    assert any(f.scale != 1.0 and f.offset != 0.0 for t in rep.terms for f in t.factors)
    rng = np.random.default_rng(5)
    x = rng.uniform(0.1, 0.45, size=(500, 2))
    u = rng.uniform(20.0, 190.0, size=(500, 4))
    true = np.array([robot_step(xi, ui) for xi, ui in zip(x, u)])
    np.testing.assert_allclose(one_step(robot_model, x, u), true, rtol=0, atol=1e-9)
    fresh = robot_data(seed=12, n_exp=1)
    e = fresh.experiments[0]
    assert np.all(fit(e.y, simulate(robot_model, e.u, y=e.y)) > 99.9)


def test_experiments_are_separate_trajectories() -> None:
    # Two experiments around different operating points: joining their signals would make a
    # false transition, and the exact noise-free coefficients would be off by far more than 1e-9
    # (1e-2 when tried).  alpha=0: plain thresholded least squares, as ridge steps can keep or
    # swap nearly collinear raw-unit terms (x1, x1^2, sin x1) at a fixed threshold.
    a = unit_data(seed=3, n=400, n_exp=1)
    b = make_data(
        unit_step, seed=4, n=400, n_exp=1, u_range=(-1.5, 1.5), x0=(-1.0, 2.0), nu=2,
        names=(("u1", "u2"), ("x1", "x2")),
    )  # fmt: skip
    model = SINDYc(normalize=False, threshold=0.01, alpha=0.0).identify(a.concat(b))
    got = coefficients_by_label(model)
    assert set(got) == set(UNIT_TERMS)
    for label, true in UNIT_TERMS.items():
        np.testing.assert_allclose(got[label], true, rtol=0, atol=1e-9, err_msg=label)


def test_model_reproduces_pysindy_on_raw_signals() -> None:
    # The normalisation is folded into the terms exactly: the saved model on raw signals gives
    # pysindy's one-step prediction on normalised signals, mapped back (to rounding).
    data = robot_data(seed=6, n=600, n_exp=1)
    options = SINDYc(threshold=1e-3)
    model = options.identify(data)
    norm = sindyc._Normalisation.of(data, True)
    sindy = options._pysindy_fit(data, norm, 1e-3)
    e = data.experiments[0]
    z_next = sindy.predict(norm.states(e.y), u=norm.inputs(e.u))
    x_next = norm.offset[:2] + np.asarray(z_next) / norm.scale[:2]
    np.testing.assert_allclose(one_step(model, e.y, e.u), x_next, rtol=0, atol=1e-12)


def test_term_correspondence_is_checked_numerically() -> None:
    data = unit_data(seed=7, n=200, n_exp=1)
    norm = sindyc._Normalisation.of(data, True)
    terms = sindyc.library_terms(data.outputs, data.inputs, norm.offset, norm.scale, 2, True)
    theta = sindyc.library_matrix(data, norm, 2, True)
    sindyc.verify_terms(terms, theta, data)
    swapped = [terms[0], terms[2], terms[1], *terms[3:]]
    with pytest.raises(PluginError, match="do not match"):
        sindyc.verify_terms(swapped, theta, data)
    with pytest.raises(PluginError, match="shape"):
        sindyc.verify_terms(terms[:-1], theta, data)


def test_library_without_sin_and_inputs() -> None:
    # An autonomous map (no inputs), degree 3, no sin: the logistic map x+ = 3.6 x - 3.6 x^2
    # (alpha=0 for the reason given in test_experiments_are_separate_trajectories).
    rng = np.random.default_rng(8)
    exps = []
    for j in range(3):
        x = np.empty((100, 1))
        x[0] = rng.uniform(0.1, 0.9)
        for k in range(99):
            x[k + 1] = 3.6 * x[k] * (1.0 - x[k])
        exps.append(Experiment(t=np.arange(100.0), u=np.zeros((100, 0)), y=x, name=f"e{j}"))
    data = Dataset(inputs=(), outputs=("x",), experiments=tuple(exps), dt=1.0)
    model = SINDYc(degree=3, sin=False, normalize=False, threshold=0.01, alpha=0.0).identify(data)
    got = coefficients_by_label(model)
    assert set(got) == {"x", "x^2"}
    np.testing.assert_allclose([got["x"][0], got["x^2"][0]], [3.6, -3.6], rtol=0, atol=1e-9)


# -- threshold sweep -----------------------------------------------------------------------------


def test_sweep_picks_and_records_a_threshold(robot_model: Model) -> None:
    notes = robot_model.provenance.notes
    lam = chosen_threshold(robot_model)
    assert robot_model.provenance.options["threshold"] is None
    swept = {float(a): float(b) for a, b in re.findall(r"([0-9.e+-]+): (-?\d+\.\d+|-inf)", notes)}
    assert set(sindyc.COARSE_THRESHOLDS) <= set(swept), "every power of ten is tried"
    assert len(swept) > len(sindyc.COARSE_THRESHOLDS), "a finer sweep follows"
    assert lam in swept and swept[lam] == max(swept.values())


def test_sweep_score_is_the_validation_fit_of_the_model(robot_model: Model) -> None:
    # The returned model is the scored candidate: its free-run fit on the held-out part equals
    # the score recorded for the chosen threshold (printed with 4 decimals).
    data = robot_data(seed=2)
    _, valid = data.split(1.0 - SINDYc().validation_fraction)
    sims = simulate_dataset(robot_model, valid)
    score = float(np.mean(fit(valid.y, np.vstack(sims))))
    key = re.escape(f"{chosen_threshold(robot_model):.3g}: ")
    recorded = re.search(key + r"(\d+\.\d+)", robot_model.provenance.notes)
    assert recorded and abs(score - float(recorded.group(1))) < 1e-4


def test_sweep_prefers_the_sparsest_of_equal_candidates(unit_model: Model) -> None:
    # Noise-free: every threshold below the smallest true coefficient (0.05) finds the exact
    # model, so the tie rule must choose the largest of them, not the first.
    lam = chosen_threshold(unit_model)
    assert 0.005 <= lam < 0.05


def test_given_threshold_skips_the_sweep(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_sweep(*args: object, **kwargs: object) -> None:
        raise AssertionError("the sweep ran although a threshold was given")

    monkeypatch.setattr(SINDYc, "_sweep", no_sweep)
    data = unit_data(seed=9, n=300, n_exp=2)
    model = SINDYc(normalize=False, threshold=0.01).identify(data)
    assert chosen_threshold(model) == 0.01
    assert "no sweep" in model.provenance.notes
    assert model.provenance.options["threshold"] == 0.01
    dense = SINDYc(normalize=False, threshold=0.0).identify(data)
    assert len(dense.representation.terms) > len(model.representation.terms)  # type: ignore[union-attr]


def test_divergent_candidates_score_minus_inf() -> None:
    data = unit_data(seed=10, n=200, n_exp=2)
    norm = sindyc._Normalisation.of(data, False)
    terms = sindyc.library_terms(data.outputs, data.inputs, norm.offset, norm.scale, 2, True)
    labels = [t.label for t in terms]
    stable = np.zeros((len(terms), 2))
    for label, coef in UNIT_TERMS.items():
        stable[labels.index(label)] = coef
    unstable = stable.copy()
    unstable[labels.index("x1^2")] = (1.5, 0.0)  # x1 grows without bound
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow warnings either
        scores = sindyc.free_run_scores(terms, np.stack([stable, unstable]), data, norm)
    assert scores[0] > 99.999
    assert scores[1] == -np.inf


# -- files, options, contract ----------------------------------------------------------------------


def test_json_round_trip_is_exact(robot_model: Model) -> None:
    again = Model.from_json(robot_model.to_json())
    assert again == robot_model
    e = robot_data(seed=13, n=300, n_exp=1).experiments[0]
    a = simulate(robot_model, e.u, y=e.y)
    b = simulate(again, e.u, y=e.y)
    assert np.array_equal(a, b)


def test_drops_terms_with_zero_coefficients(robot_model: Model) -> None:
    rep = robot_model.representation
    assert isinstance(rep, SparseMap)
    assert np.all(np.any(rep.coefficients != 0.0, axis=1))
    assert len(rep.terms) < 30  # the full library has 1 + 6 + 21 + 2 terms


def test_bad_options_are_all_reported() -> None:
    with pytest.raises(OptionError) as info:
        SINDYc(threshold=-1.0, degree=0, validation_fraction=1.5)
    problems = info.value.problems
    assert len(problems) == 3
    for word in ("threshold", "degree", "validation_fraction"):
        assert any(p.startswith(word) for p in problems), word


@pytest.mark.parametrize(
    "options",
    [
        {"validation_fraction": 0.0},
        {"validation_fraction": 1.0},
        {"threshold": float("nan")},
        {"degree": 2.0},
        {"alpha": -0.1},
        {"max_iter": 0},
        {"sin": "yes"},
    ],
)
def test_each_bad_option_is_refused(options: dict[str, object]) -> None:
    # the message names the option refused (not another one's problem)
    with pytest.raises(OptionError, match=rf"- {next(iter(options))} must be"):
        SINDYc(**options)  # type: ignore[arg-type]


def test_registered_and_options_from_text() -> None:
    entry = tk.identifiers().get("sindyc")
    assert entry.factory is SINDYc
    options = entry.create(threshold="none", degree="1", sin="false", validation_fraction="0.3")
    assert options == SINDYc(threshold=None, degree=1, sin=False, validation_fraction=0.3)


def test_too_little_data_is_refused() -> None:
    data = unit_data(seed=14, n=30, n_exp=1)
    short = data.with_experiments(
        [Experiment(t=e.t[:6], u=e.u[:6], y=e.y[:6]) for e in data.experiments]
    )
    with pytest.raises(DataError, match="threshold sweep"):
        SINDYc().identify(short)
    with pytest.raises(DataError, match="transitions for a library of 17 terms"):
        SINDYc(threshold=0.01).identify(short)


def test_deterministic_and_input_untouched() -> None:
    data = unit_data(seed=15, n=300, n_exp=2)
    before = [(e.t.copy(), e.u.copy(), e.y.copy()) for e in data.experiments]
    digest = data.hash()
    a = SINDYc().identify(data)
    b = SINDYc().identify(data)
    assert a.to_dict() == b.to_dict()
    assert data.hash() == digest
    for (t, u, y), e in zip(before, data.experiments):
        assert np.array_equal(t, e.t) and np.array_equal(u, e.u) and np.array_equal(y, e.y)


@pytest.mark.parametrize("check", identifier_checks(), ids=lambda c: c.__name__)
def test_conformance(check: Callable[[object], None]) -> None:
    check(SINDYc())
