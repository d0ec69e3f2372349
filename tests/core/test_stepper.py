"""The step-wise evaluator equals ``simulate(model, u, initial="model")`` for every model kind.

Tolerance 1e-12 (absolute, on outputs of order 1): the stepper performs the same operations
sample by sample; differences come only from the order of floating-point sums (matrix-vector
products versus the vectorised forced response, an IIR filter for single-output ARX).
"""

from __future__ import annotations

import numpy as np
import pytest

from tendonkit.errors import DataError
from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.simulate import simulate
from tendonkit.stepper import Stepper, feedthrough
from tendonkit.terms import Factor, Term

TOL = 1e-12
IN = (Signal("T1", "N"), Signal("T2", "N"))
OUT = (Signal("q1", "rad"), Signal("q2", "rad"))


def _stable(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return 0.9 * a / np.max(np.abs(np.linalg.eigvals(a)))


def state_space(rng) -> StateSpace:
    return StateSpace(
        _stable(rng, 4),
        rng.normal(size=(4, 2)),
        rng.normal(size=(2, 4)),
        rng.normal(size=(2, 2)),
        x0=rng.normal(size=4),
    )


def state_space_terms(rng) -> StateSpace:
    terms = (
        Term((Factor("q1", fn="sin", lag=0),)),  # current output (known before x[k+1])
        Term((Factor("q2", lag=1), Factor("T1", lag=2))),
        Term((Factor("T2", fn="tanh", diff=1),)),
    )
    ss = state_space(rng)
    return StateSpace(
        ss.A, ss.B, ss.C, ss.D, x0=ss.x0, terms=terms, E=0.1 * rng.normal(size=(4, 3))
    )


def arx(rng, terms: bool = True) -> ARX:
    t = (
        (
            Term((Factor("q1", fn="sin", lag=1),)),
            Term((Factor("T1", power=2), Factor("q2", lag=2, scale=1.5, offset=0.2))),
            Term((Factor("T2", lag=1), Factor("q1", lag=1))),  # bilinear (time-varying path)
            Term((Factor("T2", fn="dead_zone", param=0.3, lag=0),)),
        )
        if terms
        else ()
    )
    return ARX(
        A=(np.array([[-0.6, 0.1], [0.05, -0.5]]), np.array([[0.1, 0.0], [0.0, 0.08]])),
        B=(rng.normal(size=(2, 2)), rng.normal(size=(2, 2))),
        nk=(0, 2),
        offset=np.array([0.1, -0.2]),
        terms=t,
        term_coefficients=0.05 * rng.normal(size=(4, 2)) if terms else None,
    )


def sparse_map(rng) -> SparseMap:
    terms = (
        Term(),
        Term((Factor("x1"),)),
        Term((Factor("x2"),)),
        Term((Factor("x3", lag=1),)),
        Term((Factor("T1", lag=2),)),
        Term((Factor("T2"), Factor("x1", fn="cos"))),
    )
    coef = 0.3 * rng.normal(size=(6, 3))
    coef[1:3] = [[0.5, 0.1, 0.0], [0.0, 0.6, 0.2]]
    return SparseMap(terms, coef, output_states=(0, 2), x0=rng.normal(size=3))


ALL_BLOCKS_IN = (
    Block("delay", "T1", {"samples": 2.0}),
    Block("dead_zone", "T1", {"threshold": 0.2, "center": 0.1}),
    Block("play", "T2", {"width": 0.15}),
    Block("first_order_lag", "T2", {"pole": 0.7}),
    Block("rate_limit", "T1", {"rate": 0.4}),
    Block("saturation", "T2", {"lower": -1.0, "upper": 1.2}),
    Block("delay", "T2", {"samples": 0.0}),
    Block("second_order_section", "T1", {"b1": 0.4, "b2": -0.3, "a1": -1.1, "a2": 0.5}),
)
ALL_BLOCKS_OUT = (
    Block("first_order_lag", "q1", {"pole": 0.5}),
    Block("play", "q2", {"width": 0.05}),
    Block("rate_limit", "q2", {"rate": 0.3}),
    Block("delay", "q1", {"samples": 1.0}),
    Block("saturation", "q1", {"lower": -3.0, "upper": 3.0}),
    Block("dead_zone", "q2", {"threshold": 0.01, "center": 0.0}),
    Block("second_order_section", "q1", {"b1": -0.2, "b2": 0.1, "a1": -0.9, "a2": 0.3}),
)


def model(kind: str, blocks: bool, seed: int = 0) -> Model:
    rng = np.random.default_rng(seed)
    reps = {
        "state_space": lambda: state_space(rng),
        "state_space_terms": lambda: state_space_terms(rng),
        "arx": lambda: arx(rng),
        "arx_linear": lambda: arx(rng, terms=False),
        "sparse_map": lambda: sparse_map(rng),
    }
    rep = reps[kind]()
    states = tuple(Signal(f"x{i}") for i in range(1, 4)) if kind == "sparse_map" else ()
    return Model(
        kind,
        0.03,
        IN,
        OUT,
        rep,
        states=states,
        input_blocks=ALL_BLOCKS_IN if blocks else (),
        output_blocks=ALL_BLOCKS_OUT if blocks else (),
    )


def run(m: Model, u: np.ndarray) -> np.ndarray:
    s = Stepper(m)
    return np.array([s.step(row) for row in u])


KINDS = ["state_space", "state_space_terms", "arx", "arx_linear", "sparse_map"]


@pytest.mark.parametrize("blocks", [False, True], ids=["bare", "blocks"])
@pytest.mark.parametrize("kind", KINDS)
def test_stepper_equals_simulate(kind, blocks):
    u = np.random.default_rng(1).normal(size=(300, 2))
    m = model(kind, blocks)
    want = simulate(m, u, initial="model")
    assert np.all(np.isfinite(want))
    np.testing.assert_allclose(run(m, u), want, rtol=0, atol=TOL)


def test_single_output_arx_uses_the_same_recursion_as_the_filter_path():
    rep = ARX(A=(np.array([[-1.2]]), np.array([[0.5]])), B=(np.array([[0.3, -0.2]]),), nk=(0, 3))
    m = Model("siso", 0.1, IN, (Signal("q1"),), rep, input_blocks=ALL_BLOCKS_IN[:3])
    u = np.random.default_rng(2).normal(size=(200, 2))
    np.testing.assert_allclose(run(m, u), simulate(m, u, initial="model"), rtol=0, atol=TOL)


def test_sparse_map_states_named_like_outputs():
    # SINDYc names its states after the outputs; terms then read states, not outputs.
    rep = sparse_map(np.random.default_rng(6))
    rep = SparseMap(
        tuple(
            Term(
                tuple(
                    Factor({"x1": "q1", "x3": "q2"}.get(f.signal, f.signal), lag=f.lag)
                    for f in t.factors
                )
            )
            for t in rep.terms
        ),
        rep.coefficients,
        (0, 2),
        rep.x0,
    )
    states = (Signal("q1"), Signal("x2"), Signal("q2"))
    m = Model("sindyc-like", 0.03, IN, OUT, rep, states=states, input_blocks=ALL_BLOCKS_IN)
    u = np.random.default_rng(7).normal(size=(100, 2))
    want = simulate(m, u, initial="model")
    assert np.all(np.isfinite(want))
    np.testing.assert_allclose(run(m, u), want, rtol=0, atol=TOL)


def test_outputs_do_not_change_the_state_and_reflect_current_inputs():
    m = model("arx", blocks=True)
    u = np.random.default_rng(3).normal(size=(50, 2))
    a, b = Stepper(m), Stepper(m)
    for row in u:
        probe = a.outputs(row + 5.0)  # a different input must not leave a trace
        assert np.all(np.isfinite(probe))
        np.testing.assert_array_equal(a.outputs(row), b.outputs(row))
        np.testing.assert_array_equal(a.advance(row), b.step(row))


def test_divergence_gives_nan_from_the_same_sample_as_simulate():
    rep = StateSpace(np.array([[1e80]]), np.array([[1.0]]), np.array([[1e200]]), np.zeros((1, 1)))
    m = Model("blow-up", 1.0, (Signal("u"),), (Signal("y"),), rep)
    u = np.ones((10, 1))
    want, got = simulate(m, u, initial="model"), run(m, u)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    assert np.isnan(want).any() and not np.isnan(want).all()
    terms = sparse_map(np.random.default_rng(0))
    big = SparseMap(terms.terms, terms.coefficients * 1e60, (0, 2), terms.x0)
    m = Model(
        "sparse blow-up", 1.0, IN, OUT, big, states=(Signal("x1"), Signal("x2"), Signal("x3"))
    )
    u = np.ones((12, 2))
    want, got = simulate(m, u, initial="model"), run(m, u)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[~np.isnan(got)], want[~np.isnan(want)], rtol=1e-12)


def test_reset_restarts_and_bad_inputs_are_refused():
    m = model("sparse_map", blocks=True)
    u = np.random.default_rng(4).normal(size=(20, 2))
    s = Stepper(m)
    first = np.array([s.step(row) for row in u])
    s.reset()
    np.testing.assert_array_equal(np.array([s.step(row) for row in u]), first)
    with pytest.raises(DataError, match="takes 2 inputs"):
        s.step([1.0])
    with pytest.raises(DataError, match="finite"):
        s.step([np.nan, 0.0])


def test_feedthrough_is_structural_and_knows_startup_padding():
    m = model("arx", blocks=True)
    # nk = (0, 2): only T1 acts at lag 0 (its chain starts with a delay of 2 samples), T2
    # through the lag-0 dead-zone term; q1 has an output delay, q2 not.
    later, first = feedthrough(m), feedthrough(m, initial=True)
    assert later == {"q1": [], "q2": []}
    assert first == {"q1": ["T1", "T2"], "q2": ["T1", "T2"]}
    bare = feedthrough(model("arx", blocks=False))
    assert bare == {"q1": ["T1", "T2"], "q2": ["T1", "T2"]}
    assert feedthrough(model("sparse_map", blocks=False)) == {"q1": [], "q2": []}


@pytest.mark.parametrize("delays", [(0.4,), (1.0,), (2.3,), (1.5, 0.5)], ids=str)
def test_fractional_delays_agree_in_simulate_stepper_and_state_space(delays):
    """A delay of n + α samples is (1-α) u[k-n] + α u[k-n-1], wherever the model runs."""
    import dataclasses

    import control

    from tendonkit.realize import to_state_space

    rng = np.random.default_rng(7)
    base = model("arx_linear", False)
    base = base.replace(representation=dataclasses.replace(base.representation, offset=None))
    blocks = tuple(Block("delay", "T1", {"samples": d}) for d in delays)
    m = base.replace(input_blocks=blocks)
    u = rng.normal(size=(200, 2))
    # the explicit two-tap formula, chained, with the signal held at u[0] before the start
    v = u[:, 0].copy()
    for d in delays:
        n, a = int(np.floor(d)), d - np.floor(d)
        pad = np.concatenate([np.full(n + 1, v[0]), v])
        v = (1 - a) * pad[1 : len(v) + 1] + a * pad[: len(v)]
    want = simulate(base, np.column_stack([v, u[:, 1]]), initial="zero")
    got = simulate(m, u, initial="zero")
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # the stepper starts with the history at the first sample, as simulate does
    np.testing.assert_allclose(run(m, u), simulate(m, u, initial="model"), rtol=0, atol=TOL)
    # the realisation holds the delay taps as shift-register states (zero history)
    ss = to_state_space(m)
    u0 = u.copy()
    u0[0] = 0.0  # zero history and zero first sample: the "hold u[0]" start is then exact
    sys = control.ss(ss.A, ss.B, ss.C, ss.D, 0.03)
    y_ss = control.forced_response(sys, U=u0.T).outputs.T
    np.testing.assert_allclose(y_ss, simulate(m, u0, initial="zero"), rtol=0, atol=1e-9)


def test_a_negative_delay_is_refused():
    from tendonkit.errors import SchemaError

    with pytest.raises(SchemaError, match="delay samples must be >= 0"):
        model("arx_linear", False).replace(input_blocks=(Block("delay", "T1", {"samples": -0.5}),))


@pytest.mark.parametrize("kind", KINDS)
def test_a_saved_state_resumes_exactly_also_in_another_stepper(kind):
    """``get_state``/``set_state`` (an FMU's fmi2Get/SetFMUstate), through JSON."""
    import json

    u = np.random.default_rng(2).normal(size=(120, 2))
    m = model(kind, True)
    s = Stepper(m)
    for row in u[:50]:
        s.step(row)
    saved = json.loads(json.dumps(s.get_state()))
    first = np.array([s.step(row) for row in u[50:]])
    other = Stepper(m)
    other.set_state(saved)
    np.testing.assert_array_equal(np.array([other.step(row) for row in u[50:]]), first)
    s.set_state(saved)
    np.testing.assert_array_equal(np.array([s.step(row) for row in u[50:]]), first)
    with pytest.raises(DataError, match=r"another model|Not a saved"):
        Stepper(model("arx_linear" if kind != "arx_linear" else "sparse_map", False)).set_state(
            saved
        )
