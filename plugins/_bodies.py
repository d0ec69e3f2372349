"""Terms that act *between two bodies*: a function of the difference of two measured outputs.

A coupling between two bodies — a spring, a gear mesh, a loose joint — exerts a force that
depends on their *relative* position (or velocity), and acts on both with opposite signs.
When both positions are measured (a chain of masses, two joints, a motor and its load), the
coupling's nonlinearity is a function of ``y_i - y_j``, not of either output alone: a hardening
coupling ``k (d + α d³)``, a gap (a spring with play, ``k·dead_zone(d, b) = k·d − k·sat(d, b)``:
the linear part is the baseline's, so the term is ``sat``), a slipping joint, a hysteretic
mount.
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
from typing import Any, NamedTuple

import numpy as np

from tendonkit.dataset import Dataset
from tendonkit.terms import Factor, Term


class Pair(NamedTuple):
    """Two outputs ``a``, ``b`` and the mean and spread of ``a - b`` over the record."""

    a: str
    b: str
    mean: float
    std: float
    #: whether ``a - b`` takes both signs (more than 5 % of the samples each)
    crosses_zero: bool

    @property
    def label(self) -> str:
        """``"y1-y2"``."""
        return f"{self.a}-{self.b}"

    def centres(self) -> dict[str, float]:
        """Where a coupling's curve is centred: at the mean of the difference, and at zero
        too when the difference crosses zero away from its mean (a static load twists a shaft
        off the sensors' zero, while its gap and its spring stay centred there; a cube about
        the mean is not odd about zero)."""
        out = {"mean": self.mean}
        if self.crosses_zero and abs(self.mean) > 0.1 * self.std:
            out["zero"] = 0.0
        return out


def output_pairs(data: Dataset) -> list[Pair]:
    """Every pair of outputs with the mean and spread of their difference over the record;
    pairs whose difference does not move are left out."""
    y = data.y
    names = list(data.outputs)
    out = []
    for i, j in combinations(range(len(names)), 2):
        d = y[:, i] - y[:, j]
        sd = float(d.std())
        if sd > 0 and np.isfinite(sd):
            crosses = bool(np.mean(d > 0) > 0.05 and np.mean(d < 0) > 0.05)
            out.append(Pair(names[i], names[j], float(d.mean()), sd, crosses))
    return out


def pair_term(pair: Pair, fn: str, centre: float | None = None, **kw: Any) -> Term:
    """One term ``fn((y_a[k-1] - y_b[k-1] - centre) / std)``, centred at the mean by default."""
    offset = pair.mean if centre is None else centre
    return Term((Factor(pair.a, fn=fn, minus=pair.b, lag=1, scale=1.0 / pair.std,
                        offset=offset, **kw),))  # fmt: skip
