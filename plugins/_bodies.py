"""Terms that act *between two bodies*: a function of the difference of two measured outputs.

A coupling between two bodies — a spring, a gear mesh, a loose joint — exerts a force that
depends on their *relative* position (or velocity), and acts on both with opposite signs.
When both positions are measured (a chain of masses, two joints, a motor and its load), the
coupling's nonlinearity is a function of ``y_i - y_j``, not of either output alone: a hardening
coupling ``k (d + α d³)``, a play (a spring with a gap, ``k·dead_zone(d, b)``) in the coupling.
Every effect that models a force of the outputs tries it on every pair of outputs
(:func:`output_pairs`); the term reads both outputs one sample back
(:class:`tendonkit.terms.Factor` with ``minus``) and enters every output's equation with its
own coefficient, so the data say which bodies it pushes and how hard.

A linear term in ``d`` is in the baseline already (its output lags); only the nonlinear part
is new.  Normalised by the difference's own mean and spread, so the same fractions of a spread
serve any units.
"""

from __future__ import annotations

from itertools import combinations
from typing import Any

import numpy as np

from tendonkit.dataset import Dataset
from tendonkit.terms import Factor, Term


def output_pairs(data: Dataset) -> list[tuple[str, str, float, float]]:
    """Every pair of outputs ``(a, b, mean, std)`` with the mean and spread of ``a - b`` over
    the record; pairs whose difference does not move are left out."""
    y = data.y
    names = list(data.outputs)
    out = []
    for i, j in combinations(range(len(names)), 2):
        d = y[:, i] - y[:, j]
        sd = float(d.std())
        if sd > 0 and np.isfinite(sd):
            out.append((names[i], names[j], float(d.mean()), sd))
    return out


def pair_term(pair: tuple[str, str, float, float], fn: str, **kw: Any) -> Term:
    """One term ``fn((y_a[k-1] - y_b[k-1] - mean) / std)``."""
    a, b, mean, sd = pair
    return Term((Factor(a, fn=fn, minus=b, lag=1, scale=1.0 / sd, offset=mean, **kw),))


def label(pair: tuple[str, str, float, float]) -> str:
    """``"y1-y2"``."""
    return f"{pair[0]}-{pair[1]}"
