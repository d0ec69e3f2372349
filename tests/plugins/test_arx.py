"""ARX: recovery of known systems, orders per input, errors, speed-independent properties."""

from __future__ import annotations

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.errors import DataError, OptionError
from tendonkit.metrics import fit
from tendonkit.schema import ARX, Model, Signal
from tendonkit.testsystems import random_state_space, simulate_truth


def _arx_truth() -> Model:
    """A coupled 2-output, 3-input ARX system with different delays per input."""
    A = (np.array([[-1.2, 0.1], [0.05, -0.9]]), np.array([[0.5, -0.05], [0.0, 0.3]]))
    B = (
        np.array([[0.4, 0.0, 0.2], [0.1, 0.3, 0.0]]),
        np.array([[0.1, -0.2, 0.05], [0.0, 0.1, 0.2]]),
    )
    rep = ARX(A=A, B=B, nk=(1, 2, 3))
    return Model(
        "truth", 0.03, tuple(Signal(f"u{i}") for i in range(3)), (Signal("a"), Signal("b")), rep
    )


def test_recovers_exact_coefficients_of_a_noise_free_arx_system():
    truth = _arx_truth()
    rng = np.random.default_rng(0)
    u = rng.normal(size=(3000, 3))
    y = tk.simulate(truth, u, initial="zero")
    ds = tk.Dataset.from_arrays(u, y, 0.03, truth.input_names, truth.output_names)
    m = tk.identify(ds, "arx", na=2, nb=2, nk=(1, 2, 3))
    for got, want in zip(m.representation.A, truth.representation.A):
        np.testing.assert_allclose(got, want, atol=1e-10)  # noise-free: exact to rounding
    for got, want in zip(m.representation.B, truth.representation.B):
        np.testing.assert_allclose(got, want, atol=1e-10)


@pytest.mark.parametrize("seed", [0, 3])
def test_poles_and_markov_parameters_of_a_state_space_system(seed):
    """A 2-output order-8 system has an exact ARX form of order <= 8 (observability index 4)."""
    import control

    truth = random_state_space(8, 4, 2, seed=seed)
    ds, _ = simulate_truth(truth, 6000, noise=0.0, seed=seed + 1)
    m = tk.identify(ds, "arx", na=4, nb=4, nk=1)  # D = 0: input lags 1..4
    ident = control.minreal(m.to_control(), tol=1e-7, verbose=False)
    from scipy.optimize import linear_sum_assignment

    true_poles = np.linalg.eigvals(truth.representation.A)
    got_poles = control.poles(ident)
    assert got_poles.shape == true_poles.shape  # the minimal realisation has order 8
    dist = np.abs(true_poles[:, None] - got_poles[None, :])
    rows, cols = linear_sum_assignment(dist)  # pair every true pole with one identified pole
    assert dist[rows, cols].max() < 1e-6
    rep = truth.representation
    ss = m.to_control()
    for k in range(1, 30):  # Markov parameters C A^(k-1) B
        want = rep.C @ np.linalg.matrix_power(rep.A, k - 1) @ rep.B
        got = ss.C @ np.linalg.matrix_power(ss.A, k - 1) @ ss.B
        np.testing.assert_allclose(got, want, atol=1e-7 * np.abs(want).max() + 1e-10)


def test_fit_grows_toward_the_noise_ceiling_with_more_data():
    truth = random_state_space(8, 4, 2, seed=1)
    valid, _ = simulate_truth(truth, 5000, noise=0.05, seed=99)
    e = valid.experiments[0]
    ceiling = fit(e.y, tk.simulate(truth, e.u, y=e.y)).mean()
    fits = []
    for n in (600, 20000):
        train, _ = simulate_truth(truth, n, noise=0.05, seed=7)
        m = tk.identify(train, "arx")
        fits.append(fit(e.y, tk.simulate(m, e.u, y=e.y)).mean())
    assert fits[1] > fits[0]
    assert ceiling - fits[1] < 1.0  # within a point of what the true system achieves


def test_offset_is_estimated():
    rng = np.random.default_rng(2)
    u = rng.normal(size=(2000, 1))
    y = np.zeros((2000, 1))
    for k in range(1, 2000):
        y[k] = 0.7 * y[k - 1] + 0.5 * u[k - 1] + 0.3
    ds = tk.Dataset.from_arrays(u, y, 0.1)
    m = tk.identify(ds, "arx", na=1, nb=1, offset=True)
    assert m.representation.offset[0] == pytest.approx(0.3, abs=1e-10)


def test_option_and_data_errors_list_every_problem():
    with pytest.raises(OptionError) as info:
        tk.identify(
            tk.Dataset.from_arrays(np.arange(10.0), np.arange(10.0) ** 2, 1.0),
            "arx",
            na=-1,
            nb="x",
            ridge=-1,
        )
    assert len(info.value.problems) >= 2
    tiny = tk.Dataset.from_arrays(
        np.random.default_rng(0).normal(size=(8, 2)),
        np.random.default_rng(1).normal(size=(8, 1)),
        1.0,
    )
    with pytest.raises(DataError, match="Too few samples"):
        tk.identify(tiny, "arx")
    with pytest.raises(OptionError, match="one per input"):
        tk.identify(tiny, "arx", na=1, nb=(1, 1, 1))


def test_bilinear_recovers_an_input_dependent_gain():
    """y[k] = 0.8 y[k-1] + 0.4 u1[k-1] + 0.1 u2[k-1] y[k-1]: a stiffness set by an input."""
    rng = np.random.default_rng(4)
    n = 3000
    u = np.column_stack([rng.normal(size=n), rng.uniform(-1.0, 1.0, size=n)])
    y = np.zeros((n, 1))
    for k in range(1, n):
        y[k] = 0.8 * y[k - 1] + 0.4 * u[k - 1, 0] + 0.1 * u[k - 1, 1] * y[k - 1]
    ds = tk.Dataset.from_arrays(u, y, 0.1, ("f", "s"), ("x",))
    lin = tk.identify(ds, "arx", na=1, nb=1)
    bil = tk.identify(ds, "arx", na=1, nb=1, bilinear=True)
    rep = bil.representation
    assert [t.label for t in rep.terms] == ["f[k-1]*x[k-1]", "s[k-1]*x[k-1]"]
    np.testing.assert_allclose(rep.term_coefficients[:, 0], [0.0, 0.1], atol=1e-10)
    np.testing.assert_allclose(rep.A[0], [[-0.8]], atol=1e-10)
    np.testing.assert_allclose(rep.B[0], [[0.4, 0.0]], atol=1e-10)
    # the model simulates exactly, which the linear one cannot
    assert fit(y, tk.simulate(bil, u, initial="zero"))[0] > 99.99
    assert fit(y, tk.simulate(lin, u, initial="zero"))[0] < 99.0
    # saved and loaded, it is the same model (terms are data, not code)
    again = Model.from_json(bil.to_json())
    np.testing.assert_allclose(tk.simulate(again, u), tk.simulate(bil, u))


def test_bilinear_needs_an_output_lag():
    with pytest.raises(OptionError, match="bilinear needs na >= 1"):
        tk.identify(
            tk.Dataset.from_arrays(np.arange(50.0), np.arange(50.0), 1.0),
            "arx",
            na=0,
            bilinear=True,
        )
    with pytest.raises(OptionError, match="bilinear"):
        tk.identify(
            tk.Dataset.from_arrays(np.arange(50.0), np.arange(50.0), 1.0), "arx", bilinear="maybe"
        )
