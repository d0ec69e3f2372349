"""Parameter covariance, the simulated output's band, and frequency responses."""

from __future__ import annotations

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.compare import compare
from tendonkit.errors import SchemaError
from tendonkit.frequency import empirical_response, model_response
from tendonkit.schema import Model
from tendonkit.testsystems import random_state_space, simulate_truth
from tendonkit.uncertainty import covariance, simulate_band


def test_band_covers_the_true_response_at_its_level() -> None:
    """Over 20 noise realisations the 99 % band holds the noise-free truth ~99 % of the time.

    A band ten times too narrow covers about a tenth of the samples and fails the first
    check; one so wide that it always covers fails the second."""
    truth = random_state_space(3, 1, 1, seed=11)
    val, _ = simulate_truth(truth, 500, noise=0.0, seed=100)
    u = val.experiments[0].u
    exact = tk.simulate(truth, u, initial="zero")
    cover, widths = [], []
    for seed in range(20):
        data, _ = simulate_truth(truth, 1000, noise=0.05, seed=seed)
        model = tk.identify(data, "pem", order=3, integrator=False)
        y_hat, half = simulate_band(model, u, initial="zero")
        cover.append(np.mean(np.abs(y_hat - exact) <= half))
        widths.append(np.mean(half))
    assert 0.95 <= np.mean(cover) <= 1.0
    assert np.mean(cover) < 1.0 or np.mean(widths) < 0.05  # not trivially wide


def test_covariance_shrinks_with_data() -> None:
    truth = random_state_space(2, 1, 1, seed=4)
    sd = []
    for n in (1000, 16000):
        data, _ = simulate_truth(truth, n, noise=0.05, seed=1)
        names, cov = covariance(tk.identify(data, "pem", order=2, integrator=False))
        assert cov.shape == (len(names), len(names))
        assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > -1e-12)
        sd.append(np.sqrt(np.median(np.diag(cov))))
    assert 2.5 < sd[0] / sd[1] < 6.5  # ~ sqrt(16) = 4


def test_band_needs_a_covariance() -> None:
    model = random_state_space(2, 1, 1, seed=4)
    with pytest.raises(SchemaError, match="no parameter covariance"):
        simulate_band(model, np.zeros((10, 1)), initial="zero")


def test_model_response_matches_python_control() -> None:
    import control  # a dependency: missing, the test fails

    model = random_state_space(4, 2, 2, seed=7)
    rep = model.representation
    f = np.logspace(-2, np.log10(0.45 / model.dt), 40)
    G = model_response(model, f)
    sys = control.ss(rep.A, rep.B, rep.C, rep.D, model.dt)
    ref = np.moveaxis(sys(np.exp(2j * np.pi * f * model.dt)), -1, 0)
    assert np.allclose(G, ref, rtol=1e-10, atol=1e-12)


def test_empirical_response_recovers_a_mimo_system() -> None:
    """Two correlated inputs: the multivariable H1 estimate separates them."""
    truth = random_state_space(3, 2, 1, seed=2)
    rng = np.random.default_rng(0)
    w = rng.normal(size=(40000, 2))
    u = np.column_stack([w[:, 0], 0.6 * w[:, 0] + 0.8 * w[:, 1]])
    y = tk.simulate(truth, u, initial="zero") + 0.01 * rng.normal(size=(40000, 1))
    data = tk.Dataset(
        inputs=tuple(truth.input_names),
        outputs=tuple(truth.output_names),
        experiments=(tk.Experiment(t=np.arange(40000) * truth.dt, u=u, y=y),),
        dt=truth.dt,
    )
    f, G, coh = empirical_response(data, segment=512)
    exact = model_response(truth, f)
    err = np.abs(G - exact) / np.max(np.abs(exact), axis=0)
    assert np.median(err) < 0.02
    assert np.median(coh) > 0.95


def test_compare_plot_draws_selection_band_and_bode(tmp_path) -> None:  # type: ignore[no-untyped-def]
    truth = random_state_space(2, 1, 1, seed=5)
    data, _ = simulate_truth(truth, 2000, noise=0.02, seed=3)
    model = tk.identify(data, "pem", max_order=3, integrator=False)
    assert isinstance(model, Model) and "candidates" in model.provenance.details
    result = compare([model], data, names=["pem"], plot_dir=tmp_path)
    names = sorted(p.split("/")[-1] for p in result["figures"])
    assert names == ["band_pem.png", "bode_compare.png", "outputs_compare.png", "structure_pem.png"]
    for p in result["figures"]:
        with open(p, "rb") as fh:
            assert fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_compare_plot_draws_an_arx_structure_selection(tmp_path) -> None:  # type: ignore[no-untyped-def]
    truth = random_state_space(2, 1, 1, seed=5)
    data, _ = simulate_truth(truth, 2000, noise=0.02, seed=3)
    model = tk.identify(data, "arx", na="auto", nb="auto", nk=1, max_order=3)
    result = compare([model], data, names=["arx"], plot_dir=tmp_path)
    names = sorted(p.split("/")[-1] for p in result["figures"])
    assert names == ["bode_compare.png", "outputs_compare.png", "structure_arx.png"]
