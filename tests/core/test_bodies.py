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
