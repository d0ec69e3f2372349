"""Structured terms: evaluation, closed-form Jacobians, compiled evaluator."""

from __future__ import annotations

import numpy as np
import pytest

from tendonkit.errors import SchemaError
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
        # between two bodies: the play of a coupling, a cubic spring, a relative velocity
        Term((Factor("x", fn="dead_zone", param=0.1, minus="u", lag=1),)),
        Term((Factor("u", power=3, minus="x"),)),
        Term((Factor("x", fn="tanh", diff=2, minus="u", scale=3.0), Factor("u"))),
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


def test_a_relative_factor_reads_the_difference_of_two_signals():
    """``minus``: the stretch (or the relative velocity) between two bodies; file round trip,
    label, the signals it reads, and a factor relative to itself refused."""
    from tendonkit.terms import term_from_dict

    rng = np.random.default_rng(3)
    sig = {"x": rng.normal(size=30), "u": rng.normal(size=30)}
    get = series_getter(sig)
    f = Factor("x", fn="dead_zone", param=0.2, minus="u", lag=1, diff=1, scale=2.0, offset=0.1)
    x1, u1 = get("x", 1), get("u", 1)
    z = ((x1 - get("x", 2)) - (u1 - get("u", 2)) - 0.1) * 2.0
    np.testing.assert_array_equal(f.evaluate(get), np.sign(z) * np.maximum(np.abs(z) - 0.2, 0))
    term = Term((f,))
    assert term.signals == {"x", "u"} and term.max_lag == 2
    assert Term((Factor("q1", power=3, minus="q2", lag=1),)).label == "(q1[k-1]-q2[k-1])^3"
    problems: list[str] = []
    back = term_from_dict(term.to_dict(), "t", problems)
    assert back == term and not problems and term.to_dict()["factors"][0]["minus"] == "u"
    assert "minus" not in Term((Factor("x"),)).to_dict()["factors"][0]
    for bad in ("x", 3):
        problems = []
        assert term_from_dict({"factors": [{"signal": "x", "minus": bad}]}, "t", problems) is None
        assert problems and "minus" in problems[0]
    # the gradient with respect to the current samples: +scale on x, -scale on u
    g = Term((Factor("x", power=3, minus="u"),)).gradient(get)
    np.testing.assert_allclose(g["u"], -g["x"])
    np.testing.assert_allclose(g["x"], 3 * (sig["x"] - sig["u"]) ** 2)


def test_labels_are_readable():
    assert Term((Factor("x1", power=2), Factor("u1"))).label == "x1^2*u1"
    assert Term((Factor("q", fn="sin", lag=2),)).label == "sin(q[k-2])"
    assert Term().label == "1"


@pytest.mark.parametrize("fn", sorted(FUNCTIONS))
def test_every_function_has_value_and_derivative(fn):
    f = Factor("x", fn=fn, param=0.3, power=2)
    z = np.array([-1.0, -0.1, 0.2, 1.3])
    assert np.all(np.isfinite(f.value(z))) and np.all(np.isfinite(f.derivative(z)))


# -- hysteresis operators (play, bouc_wen): a memory carried along time ---------------------------


def test_the_play_lags_a_triangle_by_its_half_width_and_holds_at_reversals():
    z = np.concatenate([np.linspace(0, 1, 11), np.linspace(0.9, -1, 20), np.linspace(-0.9, 0, 10)])
    p = Factor("x", fn="play", param=0.25).value(z)
    assert p[0] == 0.0  # starts at the signal
    np.testing.assert_allclose(p[10], 0.75)  # rising: z - w
    np.testing.assert_allclose(p[11:13], 0.75)  # inside the gap after the reversal: held
    np.testing.assert_allclose(p[30], -0.75)  # falling: z + w
    assert np.all(np.abs(z - p) <= 0.25 + 1e-12)


def test_the_bouc_wen_state_saturates_at_one_over_the_sum_of_its_shapes():
    z = np.linspace(0, 20, 4001)  # loading far beyond the yield
    h = Factor("x", fn="bouc_wen", param=0.6, param2=0.4).value(z)
    np.testing.assert_allclose(h[-1], 1 / (0.6 + 0.4), rtol=1e-3)
    assert h[0] == 0.0 and np.all(np.diff(h) > 0)
    # a reversal unloads with the initial stiffness (dh/dz = 1 - a·sign(dz)·h - b·|h| = 1.2)
    back = Factor("x", fn="bouc_wen", param=0.6, param2=0.4).value(np.r_[z, 20 - 1e-4])
    np.testing.assert_allclose(
        (back[-1] - back[-2]) / -1e-4, 1 + 0.6 * h[-1] - 0.4 * h[-1], rtol=1e-3
    )


def test_stateful_terms_step_as_they_run_along_a_record_and_peeking_does_not_advance():
    rng = np.random.default_rng(3)
    sig = {"x": np.cumsum(rng.normal(size=300)) * 0.1, "u": rng.normal(size=300)}
    get = series_getter(sig)
    terms = [
        Term((Factor("x", fn="bouc_wen", lag=1, param=0.8, param2=-0.5, scale=2.0),)),
        Term((Factor("x", fn="play", param=0.2, diff=0), Factor("u"))),
        Term((Factor("u", fn="slew_lag", lag=1, param=0.3, param2=0.1, minus="x", weight=-2.0),)),
        Term((Factor("x", power=2),)),
    ]
    ct = CompiledTerms(terms)
    assert ct.stateful and not CompiledTerms(terms[3:]).stateful
    vals = np.array([get(name, lag) for name, lag in ct.keys])
    record = ct.evaluate(vals)
    np.testing.assert_allclose(record, np.array([t.evaluate(get, (300,)) for t in terms]))
    steps = []
    for k in range(300):
        peek = ct.evaluate(vals[:, k], commit=False)
        steps.append(ct.evaluate(vals[:, k]))
        np.testing.assert_array_equal(peek, steps[-1])
    np.testing.assert_allclose(np.array(steps).T, record, rtol=1e-14)
    # derivative with respect to the current sample, the operators' past held
    jac = ct.jacobian(vals)
    h = 1e-7
    for i in range(len(ct.keys)):
        dv = np.zeros_like(vals)
        dv[i, -1] = h
        fd = (ct.evaluate(vals + dv)[:, -1] - ct.evaluate(vals - dv)[:, -1]) / (2 * h)
        np.testing.assert_allclose(jac[:, i, -1], fd, atol=1e-5)
    with pytest.raises(SchemaError, match="one step or one record"):
        ct.evaluate(vals.reshape(len(ct.keys), 30, 10))


def test_hysteresis_factors_read_from_a_file_keep_their_shapes_and_are_checked():
    from tendonkit.terms import factor_from_dict

    f = Factor("y", fn="bouc_wen", lag=1, param=0.5, param2=-0.7)
    problems: list[str] = []
    assert factor_from_dict(f.to_dict(), "f", problems) == f and not problems
    assert f.label == "bouc_wen(y[k-1];0.5,-0.7)"
    assert factor_from_dict({"signal": "y", "fn": "play", "param": -1.0}, "g", problems) is None
    assert problems == ["g.param: a play's half-width must be >= 0, found -1.0."]


def test_a_slew_lag_follows_a_step_at_its_largest_step_then_as_a_lag():
    """``r += clip(param·(z - r), ±param2)``: an actuator that follows its command with a
    first-order lag and a rate limit; in a loop, ``z = u - weight·y``."""
    z = np.r_[0.0, np.full(60, 1.0)]
    r = Factor("u", fn="slew_lag", param=0.2, param2=0.05).value(z)
    assert r[0] == 0.0  # starts at the signal
    np.testing.assert_allclose(np.diff(r[:8]), [0.05] * 7)  # rate-limited: 0.2·(1 - r) > 0.05
    # once 0.2·(1 - r) < 0.05 it is a lag of pole 0.8
    k = int(np.argmax(0.2 * (1 - r) < 0.05)) + 1
    np.testing.assert_allclose((1 - r[k + 1 :]) / (1 - r[k:-1]), 0.8)
    # in a loop with the load: the second signal enters with its weight (a stiffness)
    rng = np.random.default_rng(7)
    sig = {"u": rng.normal(size=40), "y": rng.normal(size=40)}
    get = series_getter(sig)
    f = Factor("u", fn="slew_lag", lag=1, param=0.5, param2=0.3, minus="y", weight=-2.5)
    ref = Factor("u", fn="slew_lag", lag=1, param=0.5, param2=0.3).value(
        get("u", 1) + 2.5 * get("y", 1)
    )
    np.testing.assert_array_equal(f.evaluate(get), ref)
    assert f.label == "slew_lag((u[k-1]+2.5*y[k-1]);0.5,0.3)"
    assert Factor("u", minus="y", weight=-1.0).label == "(u+y)"
    g = Term((Factor("u", power=3, minus="y", weight=2.0),)).gradient(get)
    np.testing.assert_allclose(g["y"], -2.0 * g["u"])


def test_a_slew_lag_read_from_a_file_keeps_its_weight_and_its_shapes_are_checked():
    from tendonkit.terms import factor_from_dict

    f = Factor("u", fn="slew_lag", lag=2, param=0.1, param2=0.5, minus="y", weight=-3.0)
    problems: list[str] = []
    assert factor_from_dict(f.to_dict(), "f", problems) == f and not problems
    assert f.to_dict()["weight"] == -3.0 and "weight" not in Factor("u").to_dict()
    for bad in ({"param": 0.0, "param2": 0.5}, {"param": 1.5, "param2": 0.5}, {"param": 0.5}):
        problems = []
        assert factor_from_dict({"signal": "u", "fn": "slew_lag", **bad}, "g", problems) is None
        assert problems and "slew lag" in problems[0]
    problems = []
    assert factor_from_dict({"signal": "u", "minus": "y", "weight": "2"}, "h", problems) is None
    assert problems == ["h.weight: expected a finite number, found '2'."]
    problems = []
    assert factor_from_dict({"signal": "u", "weight": 2.0}, "w", problems) is None
    assert problems and "has none" in problems[0]


def test_the_compiled_record_loops_equal_the_step_reference():
    from tendonkit.terms import _run_stateful, _step_stateful

    z = np.cumsum(np.random.default_rng(5).normal(size=500)) * 0.2
    for fn, p, p2 in (
        ("play", 0.3, 0.0),
        ("bouc_wen", 0.7, -0.4),
        ("bouc_wen", 0.2, 0.5),
        ("slew_lag", 0.3, 0.1),
    ):
        state, ref = (np.nan, np.nan), []
        for zk in z:
            v, d, state = _step_stateful(fn, zk, state, p, p2)
            ref.append((v, d))
        np.testing.assert_allclose(np.array(_run_stateful(fn, z, p, p2)).T, ref, rtol=1e-13)


@pytest.mark.parametrize("p", [1, 2, 3, 4, 5, 8, 9])
def test_integer_powers_by_products_equal_pow_to_the_last_bits(p):
    """Integer powers up to the 8th are repeated products (``pow`` is about twenty times
    slower): the values and derivatives equal ``z ** p`` to a few units in the last place,
    ``z`` and ``z²`` exactly, the same for one sample as for a record and for the compiled
    kernel as for the numpy evaluator."""
    from tendonkit.simulate import simulate

    z = np.random.default_rng(p).normal(0.0, 2.0, 500)
    f = Factor("y", power=p)
    value, slope = f.value(z), f.derivative(z)
    np.testing.assert_allclose(value, z**p, rtol=8e-16 * p, atol=0)
    np.testing.assert_allclose(slope, p * z ** (p - 1), rtol=8e-16 * p, atol=0)
    if p <= 2:
        np.testing.assert_array_equal(value, z**p)
    assert f.value(np.float64(z[0])) == value[0]
    assert f.value(np.float64(z[0])).shape == ()
    terms = CompiledTerms([Term((f,)), Term((Factor("y", power=2), f))])
    record = terms.evaluate(z[None, :])
    np.testing.assert_array_equal(record[0], value)
    np.testing.assert_array_equal(terms.evaluate(z[None, :3])[:, 1], record[:, 1])
    # the compiled kernel evaluates the same factor to the same number: a one-step map
    # y[k] = c·y[k-1]^p + u[k-1] from y[0], simulated on both engines
    from tendonkit.schema import ARX, Model, Signal

    term = Term((Factor("y", power=p, lag=1, scale=0.5),))
    rep = ARX(
        A=(np.zeros((1, 1)),), B=(np.ones((1, 1)),), nk=(1,), terms=(term,),
        term_coefficients=np.array([[0.3]]),
    )  # fmt: skip
    model = Model("powers", 1.0, (Signal("u"),), (Signal("y"),), rep)
    u = np.random.default_rng(p + 10).normal(0.0, 0.5, (200, 1))
    fast = simulate(model, u, initial="zero", engine="compiled")
    ref = simulate(model, u, initial="zero", engine="reference")
    np.testing.assert_array_equal(fast, ref)


def test_a_term_evaluated_on_one_sample_is_its_value_not_one():
    """A getter that returns scalars gives the product (a numpy scalar is a float, which once
    made every such product read as the constant term, 1)."""
    t = Term((Factor("y", power=3), Factor("u")))
    assert float(t.evaluate(lambda name, lag: {"y": 2.0, "u": -0.5}[name])) == -4.0
    assert float(Term(()).evaluate(lambda name, lag: 7.0)) == 1.0
    np.testing.assert_array_equal(Term(()).evaluate(lambda n, k: 0.0, (3,)), np.ones(3))


@pytest.mark.parametrize("n", [1, 3, 40, 700])
def test_regressor_columns_shift_each_distinct_factor_and_are_the_same_numbers(n):
    """``term_columns_of`` evaluates each distinct memoryless factor once and shifts it to
    every lag it is read at: the columns are those of evaluating every term on the edge-padded
    lagged series, bit for bit and in the same memory layout (a least-squares fit downstream
    rounds by the layout), for every function, lags up to beyond the record, differences and
    relative factors, products of several factors and a constant."""
    from tendonkit.regression import term_columns_of

    rng = np.random.default_rng(n)
    sig = {s: rng.normal(0, 2, n) for s in ("x", "u", "w")}
    terms = [Term()]
    for fn in [f for f in FUNCTIONS if f not in ("play", "bouc_wen", "slew_lag")]:
        kw = (
            {"power": 3.0}
            if fn == "pow"
            else ({"param": 0.4} if fn in ("dead_zone", "sat", "relu") else {})
        )
        for lag in (0, 1, 4, n + 2):
            terms.append(Term((Factor("x", fn=fn, lag=lag, scale=0.7, offset=0.1, **kw),)))
        terms.append(Term((Factor("u", fn=fn, lag=2, diff=1, **kw), Factor("x", lag=3))))
        terms.append(Term((Factor("w", fn=fn, lag=1, minus="u", weight=0.6, diff=2, **kw),)))
    terms.append(Term((Factor("x", lag=1), Factor("u", fn="sin", lag=2), Factor("w", fn="abs"))))
    get = series_getter(sig)
    ct = CompiledTerms(terms)
    expected = ct.evaluate(np.array([get(name, lag) for name, lag in ct.keys])).T
    got = term_columns_of(terms, sig, n)
    assert got.shape == expected.shape == (n, len(terms))
    assert got.flags.f_contiguous == expected.flags.f_contiguous
    np.testing.assert_array_equal(got.view(np.int64), expected.view(np.int64))
