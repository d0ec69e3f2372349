"""Simulation-error refinement of any model (tendonkit.output_error)."""

from __future__ import annotations

import numpy as np

import tendonkit as tk
from tendonkit.compare import compare
from tendonkit.output_error import refine
from tendonkit.schema import Block, Model, Signal, StateSpace
from tendonkit.terms import Factor, Term
from tendonkit.testsystems import lightly_damped_oscillator


def _fit(model: Model, data: tk.Dataset) -> float:
    return float(np.mean(list(compare([model], data)["models"][0]["fit"].values())))


def test_arx_with_output_noise_reaches_the_noise_ceiling() -> None:
    """Least squares on an output-error system is biased; refined from it, the same ARX
    simulates as well as the output-error identifier's estimate (which starts from
    instrumental variables: a start in a poorer basin can stop in a local minimum, which is
    why that identifier uses one)."""
    train, _ = lightly_damped_oscillator(4000, noise=0.02, seed=1)
    valid, _ = lightly_damped_oscillator(6000, noise=0.02, seed=2)
    ls = tk.identify(train, "arx", na=2, nb=2)
    refined = refine(ls, train)
    oe = tk.identify(train, "arx", na=2, nb=2, criterion="simulation")
    assert _fit(ls, valid) < 10.0
    assert _fit(refined, valid) > 90.0
    assert abs(_fit(refined, valid) - _fit(oe, valid)) < 0.01
    assert "refined by simulation error" in refined.provenance.notes
    assert refined.provenance.training_fit["pos"] > ls.provenance.training_fit["pos"] + 10


def _terms_model(coef: float, dz: float) -> Model:
    """A state-space model with a cubic output term and a dead zone on its input."""
    rep = StateSpace(
        A=np.array([[0.9]]), B=np.array([[0.5]]), C=np.array([[1.0]]), D=np.zeros((1, 1)),
        terms=(Term((Factor("y", lag=0, power=3),)),), E=np.array([[coef]]),
    )  # fmt: skip
    return Model(
        "m", 0.01, (Signal("u"),), (Signal("y"),), rep,
        input_blocks=(Block("dead_zone", "u", {"threshold": dz, "center": 0.0}),),
    )  # fmt: skip


def test_terms_and_block_parameters_are_recovered() -> None:
    """A grey-box model with a wrong term coefficient and dead zone comes back to the truth:
    the dead zone (identifiable) to its value, the dynamics to the same input-output map
    (A, B, C and E only up to the state's scale)."""
    truth = _terms_model(-0.05, 0.3)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(2000, 1))
    data = tk.Dataset.from_arrays(u, tk.simulate(truth, u, initial="zero"), 0.01, ["u"], ["y"])
    start = _terms_model(-0.01, 0.1)
    refined = refine(start, data)
    assert abs(refined.input_blocks[0].params["threshold"] - 0.3) < 1e-3
    u2 = np.random.default_rng(1).normal(size=(1000, 1))
    fresh = tk.Dataset.from_arrays(u2, tk.simulate(truth, u2, initial="zero"), 0.01, ["u"], ["y"])
    assert _fit(start, fresh) < 90.0
    assert _fit(refined, fresh) > 99.9


def test_a_model_at_its_optimum_is_returned_unchanged() -> None:
    truth = _terms_model(-0.05, 0.3)
    rng = np.random.default_rng(1)
    u = rng.normal(size=(500, 1))
    data = tk.Dataset.from_arrays(u, tk.simulate(truth, u, initial="zero"), 0.01, ["u"], ["y"])
    assert refine(truth, data) is truth
