"""Tests of the N4SID identifier: recovery of known systems, order choice, consistency, options.

Tolerances: noise-free data are recovered to ~1e-12 (the Gram/Cholesky route keeps the
signal subspace exact); the tests allow 1e-6 so that they fail only on a real error, not on
rounding.  Noisy-data tolerances are stated at each test.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

import tendonkit as tk
from tendonkit.errors import DataError, OptionError
from tendonkit.plugins import _subspace
from tendonkit.plugins.n4sid import N4SID
from tendonkit.predict import kalman_gain
from tendonkit.schema import Model, StateSpace
from tendonkit.simulate import ss_response
from tendonkit.testsystems import random_state_space, simulate_truth


def _ss(model: Model) -> StateSpace:
    rep = model.representation
    assert isinstance(rep, StateSpace)
    return rep


def _pole_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance between optimally matched eigenvalues of ``a`` and ``b``."""
    la, lb = np.linalg.eigvals(a), np.linalg.eigvals(b)
    d = np.abs(la[:, None] - lb[None, :])
    r, c = linear_sum_assignment(d)
    return float(d[r, c].max())


def _markov_error(model: StateSpace, truth: StateSpace, k: int = 40) -> float:
    """Largest relative error of the Markov parameters ``C A^k B`` over ``k`` lags."""
    out = []
    Mi, Mt = model.B, truth.B
    for _ in range(k):
        out.append((model.C @ Mi, truth.C @ Mt))
        Mi, Mt = model.A @ Mi, truth.A @ Mt
    num = max(float(np.abs(a - b).max()) for a, b in out)
    den = max(float(np.abs(b).max()) for _, b in out)
    return num / den


def _validation_fit(model: Model, valid: tk.Dataset) -> float:
    e = valid.experiments[0]
    return float(np.mean(tk.fit(e.y, tk.simulate(model, e.u, y=e.y))))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noise_free_recovery_of_poles_and_markov_parameters(seed):
    truth = random_state_space(8, 4, 2, seed=seed)
    data, _ = simulate_truth(truth, 3000, noise=0.0, seed=seed + 10)
    model = N4SID(order=8).identify(data)
    rep, ref = _ss(model), _ss(truth)
    assert rep.n_states == 8
    assert _pole_distance(rep.A, ref.A) < 1e-6
    assert _markov_error(rep, ref) < 1e-6
    assert np.all(rep.D == 0)


def test_feedthrough_is_estimated_when_asked():
    truth = random_state_space(4, 2, 2, seed=3)
    ref = _ss(truth)
    D = np.array([[0.5, -1.0], [0.0, 2.0]])
    truth = truth.replace(representation=StateSpace(ref.A, ref.B, ref.C, D))
    data, _ = simulate_truth(truth, 2000, noise=0.0)
    rep = _ss(N4SID(order=4, feedthrough=True).identify(data))
    assert np.allclose(rep.D, D, atol=1e-8)
    assert _markov_error(rep, ref) < 1e-6
    assert np.all(_ss(N4SID(order=4).identify(data)).D == 0)  # default: no feedthrough


@pytest.mark.parametrize(("n", "nu", "ny", "seed"), [(8, 4, 2, 0), (4, 4, 2, 1), (2, 1, 1, 2)])
def test_automatic_order_on_noise_free_data(n, nu, ny, seed):
    truth = random_state_space(n, nu, ny, seed=seed)
    data, _ = simulate_truth(truth, 3000, noise=0.0, seed=seed + 1)
    model = N4SID().identify(data)
    assert _ss(model).n_states == n
    assert _markov_error(_ss(model), _ss(truth)) < 1e-6


def test_validation_fit_approaches_the_noise_ceiling_as_data_grow():
    truth = random_state_space(8, 4, 2, seed=0)
    valid, _ = simulate_truth(truth, 5000, noise=0.05, seed=99)
    ceiling = _validation_fit(truth, valid)
    fits = {}
    for n in (1000, 20000):
        data, _ = simulate_truth(truth, n, noise=0.05, seed=1)
        fits[n] = _validation_fit(N4SID(order=8).identify(data), valid)
    # Tolerance: the estimation error at 20k samples and 5 % noise costs ~0.03 points (measured).
    assert fits[20000] > ceiling - 0.5
    assert fits[20000] > fits[1000]


def test_two_experiments_are_joined_by_hankel_columns_not_signals():
    truth = random_state_space(8, 4, 2, seed=4)
    data, _ = simulate_truth(truth, 10000, noise=0.0, seed=5)
    e = data.experiments[0]
    # Two disjoint pieces: joining the signals would create a false jump at the seam, and the
    # second piece starts from a non-zero state that must be estimated separately.
    a = tk.Experiment(t=e.t[:4000], u=e.u[:4000], y=e.y[:4000], name="a")
    b = tk.Experiment(t=e.t[6000:], u=e.u[6000:], y=e.y[6000:], name="b")
    two = data.with_experiments([b, a])
    model = N4SID(order=8).identify(two)
    assert _markov_error(_ss(model), _ss(truth)) < 1e-6
    # The stored x0 is that of the first experiment (b, mid-record): free run from it is exact.
    y_sim = tk.simulate(model, b.u, initial="model")
    assert np.all(tk.fit(b.y, y_sim) > 100 - 1e-6)


def test_two_experiments_match_one_long_one_on_noisy_data():
    truth = random_state_space(8, 4, 2, seed=0)
    valid, _ = simulate_truth(truth, 5000, noise=0.01, seed=99)
    long, _ = simulate_truth(truth, 10000, noise=0.01, seed=1)
    first, _ = simulate_truth(truth, 5000, noise=0.01, seed=2)
    second, _ = simulate_truth(truth, 5000, noise=0.01, seed=3)
    f_long = _validation_fit(N4SID(order=8).identify(long), valid)
    f_two = _validation_fit(N4SID(order=8).identify(first.concat(second)), valid)
    # Same amount of data, same quality: both within 0.05 points of each other (measured 0.003).
    assert abs(f_long - f_two) < 0.05
    assert f_two > _validation_fit(truth, valid) - 0.1


def test_kalman_gain_from_residual_covariances_gives_the_optimal_predictor():
    rng = np.random.default_rng(0)
    truth = random_state_space(4, 2, 2, seed=5)
    ref = _ss(truth)
    K0 = kalman_gain(ref.A, ref.C, Q=0.5 * np.eye(4), R=np.eye(2))
    N = 12000
    u, e = rng.normal(size=(N, 2)), 0.5 * rng.normal(size=(N, 2))
    x, y = np.zeros(4), np.zeros((N, 2))
    for k in range(N):
        y[k] = ref.C @ x + e[k]
        x = ref.A @ x + ref.B @ u[k] + K0 @ e[k]
    model = N4SID(order=4).identify(tk.Dataset.from_arrays(u[:8000], y[:8000], 0.1))
    rep = _ss(model)
    assert rep.K is not None and _subspace.spectral_radius(rep.A - rep.K @ rep.C) < 1
    uv, yv = u[8000:], y[8000:]
    optimal = truth.replace(representation=StateSpace(ref.A, ref.B, ref.C, ref.D, K=K0))
    no_gain = model.replace(representation=StateSpace(rep.A, rep.B, rep.C, rep.D))
    fit_k = float(np.mean(tk.fit(yv, tk.predict(model, uv, yv))))
    # Measured: identified 92.26, optimal 92.28, default unit-covariance gain 90.83.
    assert fit_k > float(np.mean(tk.fit(yv, tk.predict(optimal, uv, yv)))) - 0.3
    assert fit_k > float(np.mean(tk.fit(yv, tk.predict(no_gain, uv, yv)))) + 0.5


def _unstable_data() -> tuple[tk.Dataset, np.ndarray]:
    rng = np.random.default_rng(0)
    A = np.array([[1.01, 0.2, 0.0], [0.0, 0.8, 0.3], [0.0, -0.3, 0.8]])
    B, C = rng.normal(size=(3, 2)), rng.normal(size=(2, 3))
    u = rng.normal(size=(400, 2))
    y = ss_response(A, B, C, np.zeros((2, 2)), u, np.zeros(3))
    return tk.Dataset.from_arrays(u, y, 0.1), A


def test_stability_is_enforced_by_default_and_optional():
    data, A = _unstable_data()
    stable = _ss(N4SID(order=3).identify(data))
    assert _subspace.spectral_radius(stable.A) < 1
    free = N4SID(order=3, stable=False).identify(data)
    assert _pole_distance(_ss(free).A, A) < 1e-6
    # B and D then come from the subspace step and still reproduce the data exactly.
    assert min(free.provenance.training_fit.values()) > 100 - 1e-6


def test_stabilize_reflects_unstable_eigenvalues_only():
    A = np.diag([1.25, 0.5, -2.0])
    lam = np.sort(np.linalg.eigvals(_subspace.stabilize(A, 0.999)).real)
    assert np.allclose(lam, [-0.5, 0.5, 0.8])


@pytest.mark.parametrize(("N", "s"), [(200, 6), (7, 6), (12, 6), (13, 2), (1001, 20)])
def test_gram_matrix_equals_that_of_the_explicit_hankel_matrix(N, s):
    # lengths a multiple of s, one more, and the shortest record (s + 1 samples)
    z = np.random.default_rng(3).normal(size=(N, 3))
    j = z.shape[0] - s + 1
    H = np.vstack([z[a : a + j].T for a in range(s)])
    assert np.allclose(_subspace.hankel_gram(z, s), H @ H.T, rtol=1e-12, atol=1e-10)


def _explicit_regressors(A, C, u, with_x0):
    """Ω[k, p] of the B/D/x0 least squares by a plain sample loop (the definition)."""
    n, ny, nu, N = A.shape[0], C.shape[0], u.shape[1], u.shape[0]
    Om = np.zeros((N, ny, n + 1, nu + 1))
    w = np.zeros((ny, n, nu))  # dual states w_pj
    v = C.copy() if with_x0 else np.zeros_like(C)  # rows (Aᵀ)ᵏ c_p
    for k in range(N):
        Om[k, :, :n, :nu] = w
        Om[k, :, :n, nu] = v
        Om[k, :, n, :nu] = u[k]
        w = np.einsum("ab,pbj->paj", A.T, w) + C[:, :, None] * u[k][None, None, :]
        v = v @ A
    return Om


@pytest.mark.parametrize("with_x0", [True, False])
def test_block_normal_equations_equal_those_of_the_explicit_regressors(monkeypatch, with_x0):
    # several chunks, a chunk end inside the record and an incomplete last block
    monkeypatch.setattr(_subspace, "CHUNK", 2 * _subspace.BLOCK)
    rng = np.random.default_rng(7)
    ref = _ss(random_state_space(3, 2, 2, seed=7))
    N = 7 * _subspace.BLOCK + 5
    u, y = rng.normal(size=(N, 2)), rng.normal(size=(N, 2))
    gram, cross = _subspace._BlockRegressors(ref.A, ref.C, 2).normal_equations(u, y, with_x0)
    Om = _explicit_regressors(ref.A, ref.C, u, with_x0).reshape(N, 2, -1)
    for p in range(2):
        expected = Om[:, p].T @ Om[:, p]
        # Tolerance: both are sums of ~N products of O(1) numbers; measured 1e-15 relative.
        assert np.allclose(gram[p], expected, rtol=1e-11, atol=1e-11 * np.abs(expected).max())
        assert np.allclose(cross[p], Om[:, p].T @ y[:, p], rtol=1e-11, atol=1e-10)


def test_block_normal_equations_do_not_depend_on_how_the_weights_are_split(monkeypatch):
    rng = np.random.default_rng(8)
    ref = _ss(random_state_space(4, 2, 2, seed=8))
    u, y = rng.normal(size=(500, 2)), rng.normal(size=(500, 2))
    whole = _subspace._BlockRegressors(ref.A, ref.C, 2).normal_equations(u, y, True)
    monkeypatch.setattr(_subspace, "G_ENTRIES", 1)  # one row of Σ Ψ ⊗ Ψ at a time
    split = _subspace._BlockRegressors(ref.A, ref.C, 2).normal_equations(u, y, True)
    for a, b in zip(whole, split):
        assert np.allclose(a, b, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("K", [1, 7, 8, 9, 64, 1000])
def test_nested_group_recursion_matches_the_step_by_step_loop(K):
    rng = np.random.default_rng(K)
    F = 0.9 * np.linalg.qr(rng.normal(size=(3, 3)))[0]
    E, x0 = rng.normal(size=(K, 3, 2)), rng.normal(size=(3, 2))
    X = _subspace._Recursion(F, group=8).run(E, x0)
    x = x0.copy()
    assert np.allclose(X[0], x0)
    for k in range(K):
        x = F @ x + E[k]
        assert np.allclose(X[k + 1], x, rtol=1e-12, atol=1e-12)


def test_decaying_responses_are_flushed_before_they_become_subnormal():
    # a fast pole decays below 1e-308 within 300 steps; subnormal numbers slow BLAS down
    E = np.zeros((5000, 2, 1))
    X = _subspace._Recursion(np.diag([0.05, 0.5]), group=8).run(E, np.ones((2, 1)))
    assert np.all((X == 0) | (np.abs(X) >= np.finfo(float).tiny))
    assert X[-1, 0, 0] == 0 and X[20, 0, 0] == pytest.approx(0.05**20, rel=1e-12)


def test_block_simulation_matches_the_sample_loop_across_chunks(monkeypatch):
    monkeypatch.setattr(_subspace, "CHUNK", 64)  # several chunks and a partial last block
    truth = random_state_space(4, 2, 2, seed=6)
    ref = _ss(truth)
    data, _ = simulate_truth(truth, 300, noise=0.0)
    e = data.experiments[0]
    B, _, x0s = _subspace.fit_input_matrices(
        ref.A, ref.C, [(e.u, e.y)], feedthrough=False, estimate_x0=True
    )
    assert np.allclose(B, ref.B, atol=1e-9) and np.allclose(x0s[0], 0, atol=1e-9)


def test_options_are_validated_all_at_once():
    with pytest.raises(OptionError) as info:
        N4SID(order=0, horizon=-1, max_order=0)
    text = str(info.value)
    assert "order" in text and "horizon" in text and "max_order" in text
    assert len(info.value.problems) == 3
    with pytest.raises(OptionError):
        N4SID(order=2.5)  # type: ignore[arg-type]
    with pytest.raises(OptionError):
        N4SID(stable="yes")  # type: ignore[arg-type]
    entry = tk.identifiers().get("n4sid")
    assert entry.create(order="8", stable="false") == N4SID(order=8, stable=False)
    with pytest.raises(OptionError):
        entry.create(order="many")


def test_horizon_too_short_for_the_order_is_an_option_error():
    data, _ = simulate_truth(random_state_space(4, 2, 2, seed=0), 500)
    with pytest.raises(OptionError, match="horizon"):
        N4SID(order=8, horizon=3).identify(data)


def test_too_few_samples_is_a_data_error():
    truth = random_state_space(4, 2, 2, seed=0)
    tiny, _ = simulate_truth(truth, 15)  # horizon 10 needs 2·10 + 1 samples per experiment
    with pytest.raises(DataError, match="samples"):
        N4SID(order=4).identify(tiny)
    short, _ = simulate_truth(truth, 100)
    N4SID(order=4, horizon=10).identify(short)  # 81 Hankel columns for 80 rows: enough
    with pytest.raises(DataError, match="columns"):  # 77 columns for 96 rows: not enough
        N4SID(order=4, horizon=12).identify(short)


def test_deterministic_and_leaves_the_data_untouched():
    data, _ = simulate_truth(random_state_space(8, 4, 2, seed=0), 3000, noise=0.01)
    before = [(e.u.copy(), e.y.copy(), e.t.copy()) for e in data.experiments]
    a = N4SID(order=8).identify(data)
    b = N4SID(order=8).identify(data)
    assert a.to_json() == b.to_json()
    for (u, y, t), e in zip(before, data.experiments):
        assert np.array_equal(u, e.u) and np.array_equal(y, e.y) and np.array_equal(t, e.t)


def test_provenance_records_order_choice_and_singular_values():
    data, _ = simulate_truth(random_state_space(4, 2, 2, seed=0), 2000, noise=0.0)
    model = tk.identify(data, "n4sid")
    assert model.provenance.identifier == "n4sid"
    assert model.provenance.options["order"] is None
    assert "order 4 (chosen" in model.provenance.notes
    assert "singular values" in model.provenance.notes


def test_scaling_does_not_change_the_model_response():
    """Signals in very different units (N vs rad) give the same model up to the unit change."""
    truth = random_state_space(4, 2, 2, seed=8)
    data, _ = simulate_truth(truth, 3000, noise=0.0)
    e = data.experiments[0]
    scale_u, scale_y = np.array([1e3, 1e-2]), np.array([1e-3, 1.0])
    scaled = tk.Dataset.from_arrays(e.u * scale_u, e.y * scale_y, data.dt)
    a, b = _ss(N4SID(order=4).identify(data)), _ss(N4SID(order=4).identify(scaled))
    b_back = StateSpace(b.A, b.B * scale_u, b.C / scale_y[:, None], b.D)
    assert _markov_error(b_back, a) < 1e-6


def _sim_rmse(model: Model, data: tk.Dataset, skip: int = 0) -> float:
    e = data.experiments[0]
    sim = tk.simulate(model, e.u, y=e.y, initial="estimate", init_window=max(skip, 1))
    return float(np.sqrt(np.mean((e.y[skip:] - sim[skip:]) ** 2)))


def test_refine_lowers_the_simulation_error_and_keeps_the_model_stable():
    """Output-error refinement (issue 17, point 1): started from the subspace model, it may
    only lower the training simulation error, and the result stays stable."""
    from tendonkit.testsystems import random_state_space, simulate_truth

    truth = random_state_space(4, 2, 2, seed=11)
    train = simulate_truth(truth, 600, noise=0.05, seed=12)[0]
    valid = simulate_truth(truth, 2000, noise=0.05, seed=13)[0]
    plain = N4SID(order=4).identify(train)
    refined = N4SID(order=4, refine=True).identify(train)
    assert "refine" in refined.provenance.notes
    assert _subspace.spectral_radius(refined.representation.A) < 1.0
    assert _sim_rmse(refined, train) <= _sim_rmse(plain, train) + 1e-12
    assert _sim_rmse(refined, valid, 50) <= _sim_rmse(plain, valid, 50) * 1.01
    with pytest.raises(OptionError, match="refine must be true or false"):
        N4SID(refine="yes")


@pytest.mark.slow
def test_refine_improves_silverbox_on_the_official_protocol(real_data):
    """Silverbox multisine test, y[50:] (README): the refined model simulates better."""
    from tendonkit.dataset import Experiment

    full = tk.Dataset.from_csv(real_data / "silverbox" / "silverbox_SNLS80mV.csv", ["u"], ["y"])
    e = full.experiments[0]

    def part(a: int, b: int) -> tk.Dataset:
        return full.with_experiments([Experiment(t=e.t[a:b] - e.t[a], u=e.u[a:b], y=e.y[a:b])])

    train, test = part(40650, 105712), part(105712, 127400)
    plain = _sim_rmse(N4SID().identify(train), test, 50)
    refined = _sim_rmse(N4SID(refine=True).identify(train), test, 50)
    assert refined < plain  # 7.03 -> 6.97 mV when written (published best linear 6.95)


def test_offset_identifies_deviations_and_stores_the_operating_point(tmp_path):
    """offset=True: a plant working around a level is identified on the deviations; the level
    is in the model (u0, y0) and simulation adds it back.  Without it the same data give a
    poor model (the level enters the subspace step as if it were dynamics)."""
    from tendonkit.compare import compare

    truth = random_state_space(3, 1, 1, seed=2)
    data, _ = simulate_truth(truth, 3000, noise=0.001, seed=4)
    e = data.experiments[0]
    shifted = data.with_experiments([dataclasses.replace(e, u=e.u + 5.0, y=e.y + 20.0)])
    plain = N4SID(order=3).identify(shifted)
    model = N4SID(order=3, offset=True).identify(shifted)
    rep = model.representation
    assert abs(float(rep.u0[0]) - (5.0 + e.u.mean())) < 1e-9
    assert abs(float(rep.y0[0]) - (20.0 + e.y.mean())) < 1e-9
    assert model.provenance.training_fit["y1"] > 99.5
    assert plain.provenance.training_fit["y1"] < 50.0
    # the singular values the order was read from are drawn by compare --plot
    figs = compare([model], shifted, names=["n4sid"], plot_dir=tmp_path)["figures"]
    assert any(p.endswith("singular_values_n4sid.png") for p in figs)
    assert len(model.provenance.details["singular_values"]) >= 3


def test_refine_keeps_the_kalman_gain_in_the_refined_coordinates():
    """refine=True changes the state basis (modal form); the subspace Kalman gain follows it,
    so the one-step predictor stays stable and predicts as well as the unrefined model's."""
    from tendonkit.metrics import fit

    truth = random_state_space(4, 2, 2, seed=3)
    train, _ = simulate_truth(truth, 3000, noise=0.05, seed=1)
    valid, _ = simulate_truth(truth, 3000, noise=0.05, seed=2)
    e = valid.experiments[0]
    fits = []
    for refine in (False, True):
        m = N4SID(order=4, refine=refine).identify(train)
        rep = m.representation
        assert rep.K is not None
        assert _subspace.spectral_radius(rep.A - rep.K @ rep.C) < 1.0
        fits.append(fit(e.y, tk.predict(m, e.u, e.y, 1)))
    assert np.all(fits[1] > fits[0] - 0.05)
