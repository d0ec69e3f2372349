"""Structured terms: evaluation, closed-form Jacobians, compiled evaluator."""

from __future__ import annotations

import numpy as np
import pytest

from tendonkit.terms import FUNCTIONS, CompiledTerms, Factor, Term, series_getter


def _terms() -> list[Term]:
    return [
        Term(),
        Term((Factor("x", power=2), Factor("u"))),
        Term((Factor("x", fn="sin", scale=2.0, offset=0.1),)),
        Term((Factor("u", fn="tanh"), Factor("x", fn="cos"))),
        Term((Factor("x", fn="dead_zone", param=0.2),)),
        Term((Factor("u", fn="sat", param=0.5), Factor("x", lag=1))),
        Term((Factor("x", fn="tanh", diff=1, scale=5.0),)),
        Term((Factor("x", fn="relu", param=0.1), Factor("u", power=3))),
        Term((Factor("x", fn="abs"),)),
    ]


def test_compiled_matches_term_by_term():
    rng = np.random.default_rng(0)
    sig = {"x": rng.normal(size=50), "u": rng.normal(size=50)}
    get = series_getter(sig)
    ct = CompiledTerms(_terms())
    vals = np.array([get(name, lag) for name, lag in ct.keys])
    expected = np.array([t.evaluate(get, (50,)) for t in _terms()])
    np.testing.assert_allclose(ct.evaluate(vals), expected, rtol=1e-14)


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(1)
    ct = CompiledTerms(_terms())
    vals = rng.normal(size=(len(ct.keys), 7)) + 0.05
    jac = ct.jacobian(vals)
    h = 1e-6
    for i in range(len(ct.keys)):
        dv = np.zeros_like(vals)
        dv[i] = h
        fd = (ct.evaluate(vals + dv) - ct.evaluate(vals - dv)) / (2 * h)
        # kinks (sign, abs, dead zone, sat, relu) are measure-zero; random points avoid them
        np.testing.assert_allclose(jac[:, i], fd, atol=1e-6)


def test_labels_are_readable():
    assert Term((Factor("x1", power=2), Factor("u1"))).label == "x1^2*u1"
    assert Term((Factor("q", fn="sin", lag=2),)).label == "sin(q[k-2])"
    assert Term().label == "1"


@pytest.mark.parametrize("fn", sorted(FUNCTIONS))
def test_every_function_has_value_and_derivative(fn):
    f = Factor("x", fn=fn, param=0.3, power=2)
    z = np.array([-1.0, -0.1, 0.2, 1.3])
    assert np.all(np.isfinite(f.value(z))) and np.all(np.isfinite(f.derivative(z)))
