"""Simulation-error refinement of any model (tendonkit.output_error)."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_the_arx_sensitivity_jacobian_equals_finite_differences() -> None:
    """The exact Jacobian of an ARX's simulation error (forward sensitivities through the
    linearised recursion, ``refine(analytic=True)``) against central differences, on random
    ARX models with terms of past outputs and inputs, bilinear gains and input blocks — of
    refine's residuals, which hold a delay's inputs before the record at the start model's
    (``input_history``)."""
    from random_models import random_model
    from scipy.optimize._numdiff import approx_derivative

    from tendonkit.dataset import Dataset, Experiment
    from tendonkit.output_error import _arx_jacobian, _arx_sensitivity_applies, _codec
    from tendonkit.simulate import _simulate_checked, aligned, input_history, simulate

    checked = 0
    for kind in ("arx_linear", "arx_terms", "arx_bilinear"):
        for seed in range(12):
            m = random_model(seed, kind, 1.0).replace(output_blocks=())
            assert _arx_sensitivity_applies(m, "estimate")  # operators with a memory too
            rng = np.random.default_rng(seed)
            u = rng.normal(0, 1, (200, len(m.inputs))).cumsum(0) * 0.1
            y = simulate(m, u, initial="zero") + rng.normal(0, 0.1, (200, len(m.outputs)))
            exp = Experiment(t=m.dt * np.arange(200), u=u, y=y, name="a")
            data = aligned(m, Dataset(m.input_names, m.output_names, (exp,), m.dt))
            theta0, decode = _codec(m, True)
            scale = np.std(data.y, axis=0)

            held = input_history(m, data.experiments[0].u, data.experiments[0].y)

            def run(th, decode=decode, data=data, scale=scale, held=held):  # type: ignore[no-untyped-def]
                e = data.experiments[0]
                sim = _simulate_checked(decode(th), e.u, e.y, "estimate", True, None, held)
                return [sim], ((e.y - sim) / scale).ravel()

            def res(th, run=run):  # type: ignore[no-untyped-def]
                return run(th)[1]

            r0 = res(theta0)
            if not np.all(np.isfinite(r0)) or np.abs(r0).max() > 1e3:
                continue  # a diverging draw: no derivative to compare
            exact = _arx_jacobian(m, data, decode, run, scale)(theta0)
            fd = approx_derivative(res, theta0, method="3-point")
            assert np.abs(exact - fd).max() <= 1e-5 * np.abs(fd).max(), (kind, seed)
            checked += 1
    assert checked >= 20


@pytest.mark.parametrize(
    "blocks",
    [
        [Block("play", "y1", {"width": 0.15})],
        [Block("saturation", "y1", {"lower": -0.8, "upper": 0.6})],
        [Block("dead_zone", "y2", {"center": 0.1, "threshold": 0.2})],
        [Block("rate_limit", "y2", {"rate": 0.05})],
        [Block("delay", "y1", {"samples": 2.4}), Block("first_order_lag", "y2", {"pole": 0.6})],
        [Block("second_order_section", "y1", {"b1": 0.3, "b2": 0.1, "a1": -0.5, "a2": 0.2})],
        # a curve, then a play on the same output: the curve's exact columns pass the play
        [
            Block("polynomial", "y1", {"c0": 0.05, "c1": 1.0, "c2": 0.1, "c3": -0.05}),
            Block("play", "y1", {"width": 0.1}),
            Block("play", "y2", {"width": 0.05}),
        ],
    ],
    ids=["play", "clip", "dead-zone", "rate", "delay+lag", "section", "curve+play"],
)
def test_the_exact_jacobian_passes_every_output_block(blocks: list[Block]) -> None:
    """A two-output ARX with memoryless terms behind output blocks of every kind: the exact
    Jacobian (forward sensitivities passed through each block's tangent) equals central
    differences in every coefficient column; the blocks' own parameters (forward differences,
    exact for a curve's coefficients) from sample 20 on.  Every block binds on a good share of
    the samples (a clip 69 %, a play 19 %), so passing one as the identity fails."""
    from scipy.optimize._numdiff import approx_derivative

    from tendonkit.output_error import _arx_jacobian, _codec, exact_jacobian
    from tendonkit.schema import ARX

    rep = ARX(
        A=(np.array([[-1.2, 0.1], [0.05, -0.9]]), np.array([[0.45, 0.0], [0.0, 0.2]])),
        B=(np.array([[0.5], [0.3]]), np.array([[0.2], [-0.1]])),
        nk=(1,),
        terms=(Term((Factor("u", fn="tanh", lag=1),)), Term((Factor("y1", power=3, lag=1),))),
        term_coefficients=np.array([[0.2, -0.1], [-0.05, 0.02]]),
    )
    m = Model("m", 0.01, (Signal("u"),), (Signal("y1"), Signal("y2")), rep,
              output_blocks=tuple(blocks))  # fmt: skip
    assert exact_jacobian(m)
    rng = np.random.default_rng(5)
    u = np.repeat(rng.normal(size=(100, 1)), 4, axis=0)
    y = tk.simulate(m, u, initial="zero") + rng.normal(0, 0.02, (400, 2))
    data = tk.Dataset.from_arrays(u, y, 0.01, ["u"], ["y1", "y2"])
    theta0, decode = _codec(m, True)
    scale = np.std(y, axis=0)

    def run(th):  # type: ignore[no-untyped-def]
        sim = tk.simulate(decode(th), u, y=y, initial="estimate")
        return [sim], ((y - sim) / scale).ravel()

    exact = _arx_jacobian(m, data, decode, run, scale)(theta0)
    fd = approx_derivative(lambda th: run(th)[1], theta0, method="3-point", rel_step=1e-7)
    n_coef = 4 * 2 + 2 * 2 + 2 * 2  # A (2 lags of 2x2), B (2 of 2x1), the terms (2x2)
    assert np.abs(exact - fd)[:, :n_coef].max() <= 1e-5 * np.abs(fd).max()
    # the blocks' parameters; a curve's exact columns leave out how the start (the outputs
    # taken back through it) moves with it, which fades within the first samples
    late = slice(2 * 20, None)  # rows from sample 20 on (two outputs per sample)
    tol = 1e-3 * max(np.abs(fd[:, n_coef:]).max(), 1.0)
    assert np.abs(exact - fd)[late, n_coef:].max() <= tol
    assert np.abs(exact[:, :n_coef]).max() > 0.1


def test_the_tall_trust_region_takes_scipys_steps() -> None:
    """The refinement's solver (the subproblem on ``JᵀJ``) follows scipy's trust-region
    reflective method without bounds: same evaluations, same minimiser, on a curved problem
    with badly scaled parameters and on one whose trial steps leave the domain."""
    from scipy.optimize import least_squares

    from tendonkit.output_error import _tall_trust_region

    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 4.0, 400)
    truth = np.array([2.0, 0.7, 300.0, 0.01])

    def model(p: np.ndarray) -> np.ndarray:
        return p[0] * np.exp(-p[1] * t) + np.sin(p[2] / 100.0 * t) * p[3] * 50.0

    y = model(truth) + 0.01 * rng.standard_normal(t.size)

    def fun(p: np.ndarray) -> np.ndarray:
        r = model(p) - y
        return r if p[1] > 0.5 else np.full(t.size, np.inf)  # a step that left the domain

    def jac(p: np.ndarray) -> np.ndarray:
        e = np.exp(-p[1] * t)
        s, c = np.sin(p[2] / 100.0 * t), np.cos(p[2] / 100.0 * t)
        return np.column_stack([e, -p[0] * t * e, c * t / 100.0 * p[3] * 50.0, s * 50.0])

    # the first start reaches the truth after one trial outside the domain; the second
    # meets the domain's edge 25 times and stops there
    for x0, converges in (([5.0, 3.0, 310.0, -0.01], True), ([0.2, 5.0, 330.0, 0.03], False)):
        x0 = np.array(x0)
        ref = least_squares(fun, x0, jac=jac, x_scale="jac", ftol=1e-10, xtol=1e-10, max_nfev=60)
        x, f, nfev = _tall_trust_region(fun, jac, x0, ftol=1e-10, xtol=1e-10, max_nfev=60)
        assert nfev == ref.nfev
        np.testing.assert_allclose(x, ref.x, rtol=1e-6)
        np.testing.assert_allclose(f @ f, ref.fun @ ref.fun, rtol=1e-9)
        assert np.allclose(x, truth, rtol=0.05) == converges


def test_a_wiener_model_is_refined_whole_with_the_exact_jacobian() -> None:
    """ARX(2, 2) followed by a cubic output curve: the Jacobian's coefficient columns (forward
    sensitivities times the curve's slope) equal finite differences; refined from a start
    with the wrong dynamics and a linear curve, the model simulates fresh data like the truth."""
    from scipy.optimize._numdiff import approx_derivative

    from tendonkit.output_error import _arx_jacobian, _codec, exact_jacobian
    from tendonkit.schema import ARX
    from tendonkit.simulate import simulate

    def wiener(a1: float, b0: float, c: tuple[float, float, float, float]) -> Model:
        rep = ARX(
            A=(np.array([[a1]]), np.array([[0.7]])),
            B=(np.array([[b0]]), np.array([[0.2]])),
            nk=(1,),
        )
        curve = Block("polynomial", "y", dict(zip(("c0", "c1", "c2", "c3"), c, strict=True)))
        return Model("w", 0.01, (Signal("u"),), (Signal("y"),), rep, output_blocks=(curve,))

    truth = wiener(-1.5, 0.4, (0.3, 1.0, 0.6, -0.1))
    rng = np.random.default_rng(3)
    u = rng.normal(size=(1500, 1))
    y = simulate(truth, u, initial="zero") + 0.01 * rng.normal(size=(1500, 1))
    data = tk.Dataset.from_arrays(u, y, 0.01, ["u"], ["y"])
    start = wiener(-1.4, 0.3, (0.0, 1.0, 0.0, 0.0))
    assert exact_jacobian(start)
    theta0, decode = _codec(start, True)
    scale = np.std(y, axis=0)

    def run(th):  # type: ignore[no-untyped-def]
        sim = simulate(decode(th), u, y=y, initial="estimate")
        return [sim], ((y - sim) / scale).ravel()

    exact = _arx_jacobian(start, data, decode, run, scale)(theta0)
    fd = approx_derivative(lambda th: run(th)[1], theta0, method="3-point")
    n_coef = 4  # a1, a2, b0, b1; the curve's c0..c3 follow (their columns leave out how the
    # start from the outputs taken back moves with the curve)
    assert np.abs(exact[:, :n_coef] - fd[:, :n_coef]).max() <= 1e-5 * np.abs(fd).max()
    u2 = np.random.default_rng(4).normal(size=(1000, 1))
    fresh = tk.Dataset.from_arrays(u2, simulate(truth, u2, initial="zero"), 0.01, ["u"], ["y"])
    refined = refine(start, data)
    assert _fit(start, fresh) < 80.0
    assert _fit(refined, fresh) > 99.0


def _loop_model(alpha: float, rate: float, weight: float) -> Model:
    """An ARX whose actuator state ``R`` follows ``u - weight·y`` with a lag and a rate limit,
    read at two lags (one operator: its shapes are shared)."""
    from tendonkit.schema import ARX

    def lag(k: int) -> Term:
        f = Factor("u", fn="slew_lag", lag=k, param=alpha, param2=rate, minus="y", weight=weight)
        return Term((f,))

    rep = ARX(
        A=(np.array([[-0.8]]),), B=(np.zeros((1, 1)),), nk=(1,),
        terms=(lag(1), lag(2)), term_coefficients=np.array([[0.3], [0.2]]),
    )  # fmt: skip
    return Model("m", 0.01, (Signal("u"),), (Signal("y"),), rep)


def test_a_slew_lags_shapes_are_refined_once_for_all_its_lags() -> None:
    """The gain, the largest step and the loop's weight of a ``slew_lag`` read at two lags
    come back to the truth from a wrong start, and stay one operator (equal at both lags).
    The record starts at rest: the operator starts at its signal (its state is not estimated;
    from a moving start the rate-limited state takes a few steps to catch up)."""
    truth = _loop_model(0.2, 0.05, 0.2)
    steps = np.repeat(np.random.default_rng(3).normal(size=(60, 1)), 40, axis=0)
    u = np.r_[np.zeros((100, 1)), steps]
    data = tk.Dataset.from_arrays(u, tk.simulate(truth, u, initial="zero"), 0.01, ["u"], ["y"])
    start = _loop_model(0.35, 0.08, 0.1)
    refined = refine(start, data)
    f1, f2 = (t.factors[0] for t in refined.representation.terms)
    assert (f1.param, f1.param2, f1.weight) == (f2.param, f2.param2, f2.weight)
    np.testing.assert_allclose([f1.param, f1.param2, f1.weight], [0.2, 0.05, 0.2], rtol=1e-6)
    assert _fit(start, data) < 70.0 and _fit(refined, data) > 99.99
    # the refined model is a valid model file: written and read back, it simulates the same
    import json

    back = Model.from_dict(json.loads(json.dumps(refined.to_dict())))
    np.testing.assert_array_equal(tk.simulate(back, u), tk.simulate(refined, u))


def _memory_model(kind: str, ny: int, seed: int) -> Model:
    """An ARX(2, 2) with terms of ``kind`` (``+``-joined): plays, Bouc-Wen operators and slew
    lags of the outputs or inputs, a clipped state tied to ``A`` (``tied``), memoryless terms."""
    from tendonkit.schema import ARX

    rng = np.random.default_rng(seed)
    outs = [f"y{i + 1}" for i in range(ny)]
    A1 = -1.5 * np.eye(ny) + 0.05 * rng.normal(size=(ny, ny))
    A = (A1, 0.7 * np.eye(ny))
    terms: list[Term] = []
    coef: list[np.ndarray] = []
    for part in kind.split("+"):
        for j, y in enumerate(outs):
            other = outs[(j + 1) % ny]
            c = np.zeros(ny)
            if part == "play":
                f = Factor(y, fn="play", lag=1, param=0.05 + 0.1 * rng.random(), scale=1.3)
                c[j] = -0.05
            elif part == "bouc_wen":
                f = Factor(y, fn="bouc_wen", lag=1, param=0.5, param2=0.2 * rng.random())
                c[j] = 0.03
            elif part == "slew":
                f = Factor("u", fn="slew_lag", lag=1, param=0.3, param2=0.05, minus=y, weight=0.4)
                c[j] = 0.05
            elif part == "between":  # a play between two bodies
                f = Factor(y, fn="play", lag=1, param=0.05, minus=other)
                c[j], c[(j + 1) % ny] = -0.03, 0.03
            elif part == "input_play":
                f = Factor("u", fn="play", lag=2, param=0.1)
                c[j] = 0.1
            elif part == "sign":
                f = Factor(y, fn="sign", lag=1, diff=1)
                c[j] = -0.01
            elif part == "play_times_input":  # a product: the play's tangent times u
                f = Factor(y, fn="play", lag=1, param=0.1)
                terms.append(Term((f, Factor("u", lag=1))))
                c[j] = -0.03
                coef.append(c)
                continue
            else:  # tied: a clip of output j at lag 1, its coefficients A1[:, j]
                f = Factor(y, fn="relu", lag=1, param=0.3)
                c = A1[:, j].copy()
            terms.append(Term((f,)))
            coef.append(c)
    rep = ARX(
        A=A,
        B=(0.3 * np.ones((ny, 1)), 0.1 * np.ones((ny, 1))),
        nk=(1,),
        offset=np.full(ny, 0.01),
        terms=tuple(terms),
        term_coefficients=np.array(coef),
    )
    return Model(
        name=kind,
        dt=0.01,
        inputs=(Signal("u"),),
        outputs=tuple(Signal(y) for y in outs),
        representation=rep,
    )


@pytest.mark.parametrize(
    "kind",
    ["play", "bouc_wen", "slew", "between", "input_play", "tied", "tied+play+sign",
     "play+bouc_wen+slew", "play_times_input+tied"],
)  # fmt: skip
@pytest.mark.parametrize("ny", [1, 2])
def test_the_exact_jacobian_passes_operators_with_a_memory_and_tied_terms(
    kind: str, ny: int
) -> None:
    """The exact Jacobian of models with terms that hold a state (a play that moves or holds, a
    Bouc-Wen operator, a slew lag in a loop with the output, a play between two bodies, a play
    of an input) and with a clipped state whose coefficients are tied to ``A``: each
    operator's tangent advanced by its rule in the regime it is in (``arx_sensitivity_terms``)
    equals finite differences in every column, the operators' shapes included (forward
    differences in both)."""
    from tendonkit.dataset import Dataset, Experiment
    from tendonkit.output_error import _arx_jacobian, _codec, tied_terms
    from tendonkit.simulate import _simulate_checked, aligned, input_history, simulate

    m = _memory_model(kind, ny, 0)
    assert bool(tied_terms(m.representation, m.output_names)) == ("tied" in kind)
    rng = np.random.default_rng(0)
    n = 300
    u = rng.normal(0, 1, (n, 1)).cumsum(0) * 0.2
    y = simulate(m, u, initial="zero") + rng.normal(0, 0.05, (n, ny))
    assert np.all(np.isfinite(y))
    exp = Experiment(t=m.dt * np.arange(n), u=u, y=y, name="a")
    data = aligned(m, Dataset(m.input_names, m.output_names, (exp,), m.dt))
    theta0, decode = _codec(m, True)
    scale = np.std(data.y, axis=0)
    held = input_history(m, exp.u, exp.y)

    def run(th):  # type: ignore[no-untyped-def]
        sim = _simulate_checked(decode(th), exp.u, exp.y, "estimate", True, None, held)
        return [sim], ((exp.y - sim) / scale).ravel()

    exact = _arx_jacobian(m, data, decode, run, scale)(theta0)
    r0 = run(theta0)[1]
    # one-sided differences: a play near a turning point changes its regime for a step of
    # one sign (the central difference then averages two regimes; the exact Jacobian is the
    # derivative in the regime at the start), so each column matches one side
    for p in range(theta0.size):
        h = 1e-7 * max(1.0, abs(float(theta0[p])))
        step = np.zeros_like(theta0)
        step[p] = h
        ahead, behind = (run(theta0 + step)[1] - r0) / h, (r0 - run(theta0 - step)[1]) / h
        tol = 1e-5 * max(np.abs(ahead).max(), 1.0)
        assert min(np.abs(exact[:, p] - ahead).max(), np.abs(exact[:, p] - behind).max()) <= tol, p
