"""The first filter of a Wiener–Hammerstein structure, found by splitting a linear model's poles
and zeros (the ``static_nonlinearity`` effect's curve between two filters)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.signal import lfilter

from tendonkit.dataset import Dataset
from tendonkit.plugins._bla_split import best_split
from tendonkit.schema import ARX, Model, Signal
from tendonkit.simulate import transform_inputs
from tendonkit.terms import Factor, Term


def _arx(a: np.ndarray, b: np.ndarray, nk: int = 0) -> Model:
    rep = ARX(
        A=tuple(np.array([[c]]) for c in a[1:]), B=tuple(np.array([[c]]) for c in b), nk=(nk,)
    )
    return Model("bla", 0.1, (Signal("u"),), (Signal("y"),), rep)


@pytest.mark.parametrize("seed", [11, 12])
def test_the_split_that_explains_the_data_is_the_first_filter(seed):
    """``y = G2(tanh(G1 u))`` with a resonant ``G1`` and a real-pole ``G2``; the linear model
    holds the poles and zeros of both.  Of the 22 splits, the one whose inner signal explains
    the data is ``G1``'s: its pole pair and its zero, as one section, the filtered input equal
    to ``G1 u`` up to the gain the curve carries."""
    rng = np.random.default_rng(seed)
    a1, b1 = np.poly([0.6 + 0.5j, 0.6 - 0.5j]).real, np.array([1.0, 0.5])
    a2, b2 = np.poly([0.9, 0.3]).real, np.array([1.0, -0.4])
    u = rng.normal(size=20000)
    x = lfilter(b1, a1, u)
    y = lfilter(b2, a2, np.tanh(x)) + 0.01 * rng.normal(size=u.size)
    data = Dataset.from_arrays(u[:, None], y[:, None], dt=0.1, inputs=["u"], outputs=["y"])
    found = best_split(_arx(np.convolve(a1, a2), np.convolve(b1, b2)), data)
    assert found is not None
    blocks, record = found
    assert [b.kind for b in blocks] == ["second_order_section"]
    p = blocks[0].params
    np.testing.assert_allclose([p["a1"], p["a2"], p["b1"], p["b2"]], [a1[1], a1[2], 0.5, 0.0],
                               atol=1e-9)  # fmt: skip
    assert record["splits_tried"] == 22
    inner = transform_inputs(data, blocks).u[:, 0]
    np.testing.assert_allclose(inner - inner[0], lfilter(b1, a1, u - u[0]), atol=1e-9)


def test_no_split_where_there_is_nothing_to_split():
    """An unstable linear part, one input of two, or a model with a nonlinear term (not a best
    linear approximation: a later step of a diagnosis): no candidate (the effect offers none)."""
    rng = np.random.default_rng(0)
    data = Dataset.from_arrays(rng.normal(size=(50, 1)), rng.normal(size=(50, 1)), dt=0.1,
                               inputs=["u"], outputs=["y"])  # fmt: skip
    assert best_split(_arx(np.array([1.0, -1.2]), np.array([1.0])), data) is None
    two = Dataset.from_arrays(rng.normal(size=(50, 2)), rng.normal(size=(50, 1)), dt=0.1,
                              inputs=["u", "v"], outputs=["y"])  # fmt: skip
    rep = ARX(A=(np.array([[-0.5]]),), B=(np.array([[1.0, 1.0]]),), nk=(0, 0))
    m = Model("two", 0.1, (Signal("u"), Signal("v")), (Signal("y"),), rep)
    assert best_split(m, two) is None
    lin = _arx(np.array([1.0, -0.5]), np.array([1.0, 0.3]))
    assert best_split(lin, data) is not None
    rep = dataclasses.replace(lin.representation, terms=(Term((Factor("y", power=3, lag=1),)),),
                              term_coefficients=np.array([[0.1]]))  # fmt: skip
    assert best_split(lin.replace(representation=rep), data) is None
