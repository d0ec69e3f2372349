"""The compiled kernel equals the numpy reference (issue 16, point 1).

Random models of every kind — ARX with linear, bilinear (``u·y``) and general terms, state
space with terms, sparse maps — with random input and output blocks (delay, including
fractional, dead zone, saturation, play, first-order lag, rate limit) and every factor function,
lag and difference, are simulated by ``engine="compiled"`` and ``engine="reference"``.  They
must agree to 1e-12 (relative to each output's range), and where a model diverges they must
diverge at the same sample (NaN from there on, also after an output block).

The two add the same numbers in a different order (numpy's matrix products against the
kernel's loops), so they differ in the last bits.  A stable model keeps that difference at the
rounding level, which is what the property test holds.  An unstable one multiplies it by its
growth, so for the first diverging draw of each kind the test holds the sample where it
diverges, the NaN from there on, and the finite samples relative to the range they reach.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from random_models import KINDS, random_model

from tendonkit.simulate import simulate


def assert_same(fast: np.ndarray, ref: np.ndarray) -> None:
    assert fast.shape == ref.shape
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(ref))
    ok = np.isfinite(ref)
    scale = np.nanmax(np.abs(np.where(ok, ref, np.nan)), axis=0, initial=0.0)
    tol = 1e-12 * np.maximum(scale, 1e-300)
    err = np.abs(np.where(ok, fast - ref, 0.0))
    worst = float(np.max(err - tol, initial=-1.0))
    assert worst <= 0.0, f"kernel and reference differ by {np.max(err):.3g} (scale {scale})"


@settings(
    max_examples=200,
    derandomize=True,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    seed=st.integers(0, 2**31),
    kind=st.sampled_from(KINDS),
    initial=st.sampled_from(["zero", "estimate", "model"]),
    n=st.integers(1, 300),
)
def test_the_kernel_equals_the_reference(seed, kind, initial, n):
    model = random_model(seed, kind, 1.0)
    rng = np.random.default_rng(seed + 1)
    u = rng.normal(0, 1, (n, len(model.inputs))).cumsum(axis=0) * 0.1
    y = rng.normal(0, 0.5, (n, len(model.outputs)))
    kw = {"y": y, "initial": initial} if initial == "estimate" else {"initial": initial}
    fast = simulate(model, u, engine="compiled", **kw)
    ref = simulate(model, u, engine="reference", **kw)
    assert_same(fast, ref)


@pytest.mark.parametrize("kind", ["arx_terms", "arx_bilinear", "ss_terms", "sparse_map"])
def test_a_diverging_model_diverges_at_the_same_sample(kind):
    for seed in range(200):
        model = random_model(seed, kind, 30.0)
        u = np.random.default_rng(seed).normal(0, 1, (400, len(model.inputs)))
        ref = simulate(model, u, engine="reference", initial="zero")
        bad = np.isnan(ref).any(axis=1)
        if bad.any() and not bad[0]:
            fast = simulate(model, u, engine="compiled", initial="zero")
            assert_same(fast, ref)
            first = int(np.argmax(bad))
            assert np.isnan(fast[first:]).all() and np.isfinite(fast[:first]).all()
            return
    pytest.fail(f"no diverging {kind} model among 200 seeds")  # the test must test something


def test_an_unknown_engine_is_refused():
    model = random_model(1, "arx_linear", 1.0)
    from tendonkit.errors import DataError

    with pytest.raises(DataError, match="engine must be"):
        simulate(model, np.zeros((5, len(model.inputs))), engine="fortran")


@pytest.mark.parametrize(("nx", "ny", "nc"), [(1, 1, 1), (4, 2, 3), (7, 3, 5)])
def test_unit_responses_are_the_impulse_responses_convolved_with_each_signal(nx, ny, nc):
    """The output-error regressors (``unit_responses``: every signal entering every state)
    equal the convolution of the impulse response ``C A^m e_i`` with the signal, delayed one
    sample — computed here from explicit matrix powers."""
    from tendonkit.simulate import unit_responses

    rng = np.random.default_rng(nx * 100 + nc)
    A = rng.standard_normal((nx, nx))
    A *= 0.9 / max(abs(np.linalg.eigvals(A)))
    C = rng.standard_normal((ny, nx))
    N = 60
    S = rng.standard_normal((N, nc))
    H = np.stack([C @ np.linalg.matrix_power(A, m) for m in range(N)])  # (N, ny, nx)
    want = np.zeros((N, ny, nx * nc))
    for i in range(nx):
        for c in range(nc):
            for o in range(ny):
                want[1:, o, i * nc + c] = np.convolve(H[:, o, i], S[:, c])[: N - 1]
    got = unit_responses(A, C, S)
    assert got.shape == (N, ny, nx * nc)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize("seed", range(6))
def test_terms_of_inputs_taken_from_their_series_are_the_same_numbers(seed):
    """``arx_loop`` takes the memoryless terms of inputs only from series computed once per
    distinct factor (``input_bases``, ``input_series``) instead of evaluating every factor at
    every sample: the simulation is the same bit for bit as with every term evaluated in the
    loop, on ARX models whose terms mix inputs (powers and curves at several lags, differences,
    a relative factor), outputs and operators with a memory."""
    from tendonkit import _kernel
    from tendonkit.schema import ARX, Model, Signal
    from tendonkit.terms import Factor, Term

    rng = np.random.default_rng(seed)
    inputs, outputs = ["u1", "u2"], ["y1"]
    terms = [
        Term((Factor("u1", fn="pow", power=float(p), lag=lag),))
        for p in (2, 3)
        for lag in (1, 2, 3)
    ]
    terms += [
        Term((Factor("u2", fn="tanh", lag=1, scale=0.7), Factor("u1", lag=2))),
        Term((Factor("u2", fn="abs", lag=2, diff=1),)),
        Term((Factor("u1", fn="sin", lag=1, minus="u2", weight=0.8),)),
        Term((Factor("y1", fn="pow", power=3.0, lag=1),)),
        Term((Factor("u1", fn="pow", power=2.0, lag=1), Factor("y1", fn="sign", lag=1, diff=1))),
        Term((Factor("y1", fn="play", lag=1, param=0.1),)),
        Term(),
    ]
    nt = len(terms)
    rep = ARX(
        A=(np.array([[-1.2]]), np.array([[0.5]])),
        B=tuple(rng.normal(0, 0.3, (1, 2)) for _ in range(3)),
        nk=(1, 1),
        terms=tuple(terms),
        # the cubic of the output restoring (negative): the draws stay finite
        term_coefficients=rng.normal(0, 0.01, (nt, 1)) * np.where(np.arange(nt) == 9, 0, 1)[:, None]
        - 0.05 * (np.arange(nt) == 9)[:, None],
    )
    model = Model(
        name="mixed terms",
        inputs=tuple(Signal(n) for n in inputs),
        outputs=tuple(Signal(n) for n in outputs),
        dt=0.01,
        representation=rep,
    )
    u = rng.normal(0, 1, (400, 2)).cumsum(axis=0) * 0.1
    y = rng.normal(0, 0.5, (400, 1))
    fast = simulate(model, u, y=y, initial="estimate", engine="compiled")

    flat = _kernel.flatten(rep.terms, {"u1": 0, "u2": 1}, {"y1": 0})
    pre, _, _ = _kernel.input_bases(flat)
    assert pre.tolist() == [True] * 9 + [False, False, False, True]
    original = _kernel.input_bases
    try:  # every term evaluated in the loop, as before the series
        _kernel.input_bases = lambda f: (
            np.zeros(f.n_terms, dtype=np.bool_),
            *original(f)[1:],
        )
        slow = simulate(model, u, y=y, initial="estimate", engine="compiled")
    finally:
        _kernel.input_bases = original
    assert np.all(np.isfinite(fast))
    np.testing.assert_array_equal(fast.view(np.int64), slow.view(np.int64))
