"""Terms between two bodies (plugins/_bodies.py): the pairs of outputs an effect tries."""

from __future__ import annotations

import numpy as np


def test_pairs_of_many_outputs_are_screened_by_the_training_residual(monkeypatch):
    """Effects between two bodies try every pair of up to four outputs; with more, the pairs
    whose nonlinear probes the baseline's training residual follows most closely (here the
    cube of y3 - y4 in the residual of y1, a coupling's hardening that the linear model left)."""
    from types import SimpleNamespace

    from tendonkit.dataset import Dataset
    from tendonkit.plugins import _bodies

    rng = np.random.default_rng(2)
    n = 2000
    y = np.cumsum(rng.normal(size=(n, 5)), axis=0) * 0.01 + rng.normal(size=(n, 5))
    names = [f"y{i}" for i in range(5)]
    data = Dataset.from_arrays(rng.normal(size=(n, 1)), y, dt=0.01, inputs=["u"], outputs=names)

    def residual_of(a: int, b: int) -> np.ndarray:
        z = y[:, a] - y[:, b]
        z = (z - z.mean()) / z.std()
        out = 0.05 * rng.normal(size=(n, 5))
        out[:, 1] += 0.02 * (z**3 - 3 * z)
        return out

    ctx = SimpleNamespace(train=data, residuals=SimpleNamespace(residual=residual_of(3, 4)))
    assert len(_bodies.output_pairs(data)) == 10
    assert len(_bodies.screened_pairs(ctx)) == _bodies.MAX_PAIRS == 6  # type: ignore[arg-type]
    monkeypatch.setattr(_bodies, "MAX_PAIRS", 1)  # the one pair that ranks first
    assert [(p.a, p.b) for p in _bodies.screened_pairs(ctx)] == [("y3", "y4")]  # type: ignore[arg-type]
    ctx.residuals.residual = residual_of(0, 2)
    assert [(p.a, p.b) for p in _bodies.screened_pairs(ctx)] == [("y0", "y2")]  # type: ignore[arg-type]
    # up to MAX_PAIRS pairs, every pair, without looking at the residual
    monkeypatch.setattr(_bodies, "MAX_PAIRS", 6)
    four = Dataset.from_arrays(data.u, y[:, :4], dt=0.01, inputs=["u"], outputs=names[:4])
    assert len(_bodies.screened_pairs(SimpleNamespace(train=four, residuals=None))) == 6  # type: ignore[arg-type]


def test_a_position_and_its_speed_are_not_a_pair_of_bodies():
    """The difference of a position and a speed of one body is the speed (the larger signal):
    not a coupling, and a narrow sat of it would be the speed's sign, friction's structure.
    Two coupled bodies' positions are a pair."""
    from tendonkit.dataset import Dataset
    from tendonkit.plugins import _bodies

    t = np.arange(3000) * 0.01
    x = np.sin(10 * t) * 0.1 + 0.05 * np.sin(3.1 * t)
    v = np.gradient(x, 0.01)
    both = Dataset.from_arrays(np.sin(np.arange(3000.0))[:, None], np.column_stack([x, v]), dt=0.01,
                               inputs=["u"], outputs=["x", "v"])  # fmt: skip
    assert _bodies.output_pairs(both) == []
    x2 = 0.8 * x + 0.02 * np.sin(17 * t)  # a second body, coupled to the first
    two = Dataset.from_arrays(np.sin(np.arange(3000.0))[:, None], np.column_stack([x, x2]), dt=0.01,
                              inputs=["u"], outputs=["x1", "x2"])  # fmt: skip
    assert [(p.a, p.b) for p in _bodies.output_pairs(two)] == [("x1", "x2")]


def test_a_coupling_off_zero_is_also_centred_at_zero():
    """A difference that crosses zero away from its mean (a static load twists the shaft off
    the sensors' zero) is centred at zero too; one about its mean, or one that never crosses
    zero, only at its mean."""
    from tendonkit.plugins._bodies import Pair

    assert Pair("a", "b", 0.3, 1.0, True).centres() == {"mean": 0.3, "zero": 0.0}
    assert Pair("a", "b", 0.05, 1.0, True).centres() == {"mean": 0.05}
    assert Pair("a", "b", 3.0, 1.0, False).centres() == {"mean": 3.0}


def test_every_pair_together_must_earn_its_extra_terms():
    """The candidate with every pair together is kept only where it lowers the best single
    pair's training misfit (100 − fit) by 1 % (the automatic ARX's parsimony): the cubes of all
    three differences of a chain fitted 0.8 % better than the one pair that holds the spring,
    and simulated the validation record 6 points worse."""
    from tendonkit.dataset import Dataset
    from tendonkit.diagnose import Context
    from tendonkit.plugins import _bodies

    rng = np.random.default_rng(0)
    data = Dataset.from_arrays(rng.normal(size=(10, 1)), rng.normal(size=(10, 3)), dt=0.01,
                               inputs=["u"], outputs=["x1", "x2", "x3"])  # fmt: skip
    models = {label: object() for label in ("x1-x2", "x2-x3", "each output", "all")}

    def chosen(scores: dict[str, float | None]) -> object:
        ctx = Context(train=data, baseline=None, identifier=None, residuals=None)  # type: ignore[arg-type]
        ctx.score = lambda m: next(  # type: ignore[method-assign]
            s if s is not None else float("-inf") for k, s in scores.items() if models[k] is m
        )
        between = {"x1-x2": "x1-x2", "x2-x3": "x2-x3", "all": ["x1-x2", "x2-x3"]}
        cands = [
            ({"between": between[label]} if label in between else {"structure": "odd powers"},
             lambda d, label=label: models[label])
            for label in models
        ]  # fmt: skip
        params, model, score = _bodies.select_pairs(ctx, cands)
        label = next(k for k, m in models.items() if m is model)
        assert score == scores[label]  # the model, its score and its params belong together
        assert params.get("between") == between.get(label)
        return model

    # all pairs 0.85 % better than the best single pair: not earned, the single pair is kept
    mine = {"x1-x2": 90.0, "x2-x3": 96.46, "each output": 80.0}
    assert chosen({**mine, "all": 96.49}) is models["x2-x3"]
    # ... or a candidate of another kind, where that fits better than every single pair
    assert chosen({**mine, "each output": 96.48, "all": 96.49}) is models["each output"]
    # 4 % better: earned
    assert chosen({**mine, "all": 96.60}) is models["all"]
    # a single pair that fits best is chosen as before; no single pair that fits: all pairs
    assert chosen({**mine, "x1-x2": 97.0, "all": 96.49}) is models["x1-x2"]
    assert (
        chosen({"x1-x2": None, "x2-x3": None, "each output": 80.0, "all": 96.49}) is models["all"]
    )
