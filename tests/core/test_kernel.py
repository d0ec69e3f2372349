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

from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.simulate import simulate
from tendonkit.terms import FUNCTIONS, Factor, Term

KINDS = ("arx_linear", "arx_terms", "arx_bilinear", "ss_terms", "sparse_map")


def _factor(rng: np.random.Generator, names: list[str], min_lag: dict[str, int]) -> Factor:
    name = str(rng.choice(names))
    fn = str(rng.choice(list(FUNCTIONS)))
    return Factor(
        name,
        fn=fn,
        power=int(rng.integers(1, 4)),
        lag=int(rng.integers(min_lag.get(name, 0), 4)),
        diff=int(rng.choice([0, 0, 1, 2])),
        scale=float(rng.uniform(0.5, 2.0)),
        offset=float(rng.normal(0.0, 0.2)),
        param=float(rng.uniform(0.0, 0.5)),
    )


def _terms(rng, names, min_lag, n) -> tuple[Term, ...]:
    return tuple(
        Term(tuple(_factor(rng, names, min_lag) for _ in range(int(rng.integers(0, 3)))))
        for _ in range(n)
    )


def _blocks(rng, names: list[str]) -> tuple[Block, ...]:
    out = []
    for name in names:
        kind = str(
            rng.choice(
                [
                    "none",
                    "delay",
                    "dead_zone",
                    "saturation",
                    "play",
                    "first_order_lag",
                    "rate_limit",
                ]
            )
        )
        params = {
            "delay": {"samples": float(rng.choice([2.0, rng.uniform(0, 3)]))},
            "dead_zone": {"threshold": float(rng.uniform(0, 0.3)), "center": 0.1},
            "saturation": {"lower": -0.6, "upper": float(rng.uniform(0.2, 0.8))},
            "play": {"width": float(rng.uniform(0.01, 0.3))},
            "first_order_lag": {"pole": float(rng.uniform(0, 0.9))},
            "rate_limit": {"rate": float(rng.uniform(0.01, 0.3))},
        }.get(kind)
        if params is not None:
            out.append(Block(kind, name, params))
    return tuple(out)


def random_model(seed: int, kind: str, gain: float) -> Model:
    """A random model of ``kind``; ``gain`` > 1 makes divergence likely."""
    rng = np.random.default_rng(seed)
    nu, ny = int(rng.integers(1, 4)), int(rng.integers(1, 3))
    ins = [f"u{i + 1}" for i in range(nu)]
    outs = [f"y{i + 1}" for i in range(ny)]
    past = {n: 1 for n in outs}  # ARX terms read past outputs only
    states: tuple[Signal, ...] = ()
    if kind.startswith("arx"):
        na, nb = int(rng.integers(0, 4)), int(rng.integers(1, 4))
        A = tuple(rng.normal(0, 0.3 / (na or 1), (ny, ny)) * gain for _ in range(na))
        B = tuple(rng.normal(0, 0.5, (ny, nu)) for _ in range(nb))
        terms: tuple[Term, ...] = ()
        if kind == "arx_terms":
            terms = _terms(rng, ins + outs, past, int(rng.integers(1, 6)))
        elif kind == "arx_bilinear":
            terms = tuple(
                Term((Factor(str(rng.choice(ins))), Factor(str(rng.choice(outs)), lag=lag)))
                for lag in range(1, int(rng.integers(2, 5)))
            ) + _terms(rng, ins, {}, 2)
        coef = rng.normal(0, 0.1, (len(terms), ny)) * gain if terms else None
        rep: ARX | StateSpace | SparseMap = ARX(
            A,
            B,
            tuple(int(k) for k in rng.integers(0, 3, nu)),
            offset=rng.normal(0, 0.1, ny),
            terms=terms,
            term_coefficients=coef,
        )
    elif kind == "ss_terms":
        n = int(rng.integers(1, 5))
        A = rng.normal(0, 0.4 / np.sqrt(n), (n, n)) * gain
        terms = _terms(rng, ins + outs, {}, int(rng.integers(1, 5)))
        rep = StateSpace(
            A,
            rng.normal(0, 0.5, (n, nu)),
            rng.normal(0, 1.0, (ny, n)),
            rng.normal(0, 0.1, (ny, nu)),
            terms=terms,
            E=rng.normal(0, 0.1, (n, len(terms))) * gain,
        )
    else:
        nx = ny + int(rng.integers(0, 2))
        states = tuple(Signal(f"x{i + 1}") for i in range(nx))
        snames = [s.name for s in states]
        lin = tuple(Term((Factor(s),)) for s in snames)
        terms = (Term(()), *lin, *_terms(rng, snames + ins, {}, int(rng.integers(1, 6))))
        coef = rng.normal(0, 0.05, (len(terms), nx)) * gain
        coef[1 : 1 + nx] += np.diag(rng.uniform(0.3, 0.8, nx)) * gain
        rep = SparseMap(terms, coef, tuple(range(ny)), x0=rng.normal(0, 0.1, nx))
    return Model(
        f"random_{kind}",
        0.01,
        tuple(Signal(n) for n in ins),
        tuple(Signal(n) for n in outs),
        rep,
        states=states,
        input_blocks=_blocks(rng, ins),
        output_blocks=_blocks(rng, outs),
    )


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
