"""Terms that act *between two bodies*: a function of the difference of two measured outputs.

A coupling between two bodies — a spring, a gear mesh, a loose joint — exerts a force that
depends on their *relative* position (or velocity), and acts on both with opposite signs.
When both positions are measured (a chain of masses, two joints, a motor and its load), the
coupling's nonlinearity is a function of ``y_i - y_j``, not of either output alone: a hardening
coupling ``k (d + α d³)``, a gap (a spring with play,
``k·dead_zone(d, b) = k·d − k·sat(d, b)``: the linear part is the baseline's, so the term is
``sat``), a slipping joint, a hysteretic mount.
Every effect that models a force of the outputs tries it on every pair of outputs
(:func:`output_pairs`); the term reads both outputs one sample back
(:class:`tendonkit.terms.Factor` with ``minus``) and enters every output's equation with its
own coefficient, so the data say which bodies it pushes and how hard.

A linear term in ``d`` is in the baseline already (its output lags); only the nonlinear part
is new.  Normalised by the difference's own spread, so the same fractions of a spread serve
any units, and centred at its mean — and at zero too where the difference crosses zero away
from its mean (:meth:`Pair.centres`).

With ``n`` outputs there are ``n(n−1)/2`` pairs and every effect tries each: beyond
:data:`MAX_PAIRS` (four outputs), only the pairs whose difference the baseline's training
residuals follow most closely are tried (:func:`screened_pairs`).

Every pair together is a candidate too (a chain whose every coupling hardens), and it must
earn its extra terms: it is kept only where its training misfit is :data:`TOGETHER_MARGIN`
below the best single pair's (:func:`select_pairs`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from itertools import combinations
from typing import Any, NamedTuple

import numpy as np

from tendonkit.dataset import Dataset
from tendonkit.diagnose import Context, Extension
from tendonkit.plugins._arx_structure import PARSIMONY
from tendonkit.schema import ARX, Model
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


#: A pair whose difference follows one of its two outputs this closely (absolute correlation)
#: is that output in disguise, not a coupling: left out.
SAME_AS_ONE = 0.95


def velocity(y: np.ndarray, m: int) -> np.ndarray:
    """``y[k] - y[k-m]`` (zero for the first ``m`` samples)."""
    v = np.zeros_like(y)
    v[m:] = y[m:] - y[:-m]
    return v


def input_lags(model: Model, m: int) -> list[int]:
    """The lags at which ``model`` reads input ``m`` (ARX: ``nk .. nk + nb - 1`` from lag 1 on,
    where terms can read it — none when ``nk = 0`` and ``nb = 1``; any other representation:
    1 to 4) — where a curve on that input's path is put."""
    rep = model.representation
    if isinstance(rep, ARX) and len(rep.B) and len(rep.nk) > m:
        first = max(int(rep.nk[m]), 1)
        return list(range(first, int(rep.nk[m]) + len(rep.B)))
    return [1, 2, 3, 4]


def both_signs(x: np.ndarray) -> bool:
    """Whether ``x`` takes both signs, on more than 5 % of its samples each."""
    return bool(np.mean(x > 0) > 0.05 and np.mean(x < 0) > 0.05)


def difference(y: np.ndarray, outputs: Sequence[str], a: str, b: str) -> np.ndarray:
    """``y_a - y_b`` from the stacked outputs ``y`` (columns named by ``outputs``)."""
    return y[:, list(outputs).index(a)] - y[:, list(outputs).index(b)]


def output_pairs(data: Dataset) -> list[Pair]:
    """Every pair of outputs with the mean and spread of their difference over the record.

    Left out: pairs whose difference does not move, and pairs whose difference is one of the
    two outputs in disguise (correlation above :data:`SAME_AS_ONE`): a position and a speed of
    one body, whose difference is the speed — a narrow ``sat`` of it is the speed's sign, the
    friction effect's structure, and on a mass measured by both it gained +10.2 beside
    friction's +10.4.  The outputs of two coupled bodies share their common motion and differ
    by the coupling's stretch (0.3–0.85 on the plants tried).
    """
    y = data.y
    out = []
    for (i, a), (j, b) in combinations(enumerate(data.outputs), 2):
        d = difference(y, data.outputs, a, b)
        sd = float(d.std())
        if not (sd > 0 and np.isfinite(sd)):
            continue
        same = np.nan_to_num(np.corrcoef(np.vstack([d, y[:, i], y[:, j]]))[0, 1:])
        if np.max(np.abs(same)) <= SAME_AS_ONE:
            out.append(Pair(a, b, float(d.mean()), sd, both_signs(d)))
    return out


def pair_term(pair: Pair, fn: str, centre: float | None = None, **kw: Any) -> Term:
    """One term ``fn((y_a[k-1] - y_b[k-1] - centre) / std)``, centred at the mean by default."""
    offset = pair.mean if centre is None else centre
    return Term((Factor(pair.a, fn=fn, minus=pair.b, lag=1, scale=1.0 / pair.std,
                        offset=offset, **kw),))  # fmt: skip


#: Most pairs of outputs an effect tries (every pair of four outputs); more are screened.
MAX_PAIRS = 6


def _probes(d: np.ndarray) -> list[np.ndarray]:
    """Nonlinear functions of a difference that a coupling's force follows — its cube, a gap's
    ``sat``, the sign of its velocity — each without its part along ``1`` and ``d``."""
    z = (d - d.mean()) / (d.std() or 1.0)
    vel = velocity(z, 3)
    basis = np.column_stack([np.ones_like(z), z])
    out = []
    for p in (z**3, np.clip(z, -0.1, 0.1), np.sign(vel)):
        p = p - basis @ np.linalg.lstsq(basis, p, rcond=None)[0]
        out.append(p / (np.linalg.norm(p) or 1.0))
    return out


def screened_pairs(ctx: Context) -> list[Pair]:
    """:func:`output_pairs` of the training data; beyond :data:`MAX_PAIRS`, the pairs whose
    probes (:func:`_probes`) the baseline's free-run training residual of any output follows
    most closely (largest absolute correlation), in the pairs' order.  Computed once per
    context (several effects ask)."""
    cache = getattr(ctx, "_cache", None)
    if cache is None:
        return _screened(ctx)
    if "pairs" not in cache:
        cache["pairs"] = _screened(ctx)
    return list(cache["pairs"])


def _screened(ctx: Context) -> list[Pair]:
    pairs = output_pairs(ctx.train)
    if len(pairs) <= MAX_PAIRS:
        return pairs
    res = np.asarray(ctx.residuals.residual, dtype=float)
    y = ctx.train.y
    if res.shape[0] != len(y) or len(y) < 10:  # not sample for sample: no screen
        return pairs[:MAX_PAIRS]
    res = np.where(np.isfinite(res), res, 0.0)
    res = (res - res.mean(axis=0)) / np.where(res.std(axis=0) > 0, res.std(axis=0), 1.0)
    score = []
    for p in pairs:
        probes = _probes(difference(y, ctx.train.outputs, p.a, p.b))
        score.append(max(float(np.max(np.abs(pr @ res))) for pr in probes))
    keep = sorted(np.argsort(score)[::-1][:MAX_PAIRS])
    return [pairs[i] for i in keep]


#: Every pair together is chosen over the best single pair only where it lowers the training
#: misfit (``100 − fit``, the normalised RMS free-run error) by this share: its extra terms
#: must earn their place, as in the automatic ARX's choice of orders (1 %,
#: :mod:`tendonkit.plugins._arx_structure`).  Fitted by least squares, the terms of the pairs
#: without a coupling follow the noise of the record: on a chain of three masses hardening
#: between the last two, the cubes of all three differences fitted the training record
#: 0.8 % better than the one true pair (misfit 3.51 against 3.54 %) and simulated the
#: validation record 6 points worse (91.5 against 97.5 %; benchmarks/bench_diagnose_chain.py,
#: seed 812).
TOGETHER_MARGIN = PARSIMONY


def select_pairs(
    ctx: Context, cands: Sequence[tuple[dict[str, Any], Callable[[Dataset], Model]]]
) -> tuple[dict[str, Any], Model | None, float]:
    """:meth:`Context.select` of an effect's candidates, with every pair together (params
    ``between`` a list) kept only where it beats the best single pair (``between`` one
    label) by :data:`TOGETHER_MARGIN` of its training misfit; otherwise the best of the other
    candidates (a single pair, or a term of each output) is chosen."""

    def together(c: tuple[dict[str, Any], Any]) -> bool:
        return isinstance(c[0].get("between"), list)

    # the others first, then every pair together against them: each candidate built once
    params, model, score, tried = ctx.select([c for c in cands if not together(c)])
    p_all, m_all, s_all, _ = ctx.select([c for c in cands if together(c)])
    if m_all is None or not s_all > score:
        return params, model, score
    singles = [t["score"] for t in tried
               if isinstance(t["params"].get("between"), str) and t.get("score") is not None]  # fmt: skip
    one = max((v for v in singles if math.isfinite(v)), default=None)
    if one is None or 100.0 - s_all < (1.0 - TOGETHER_MARGIN) * (100.0 - one):
        return p_all, m_all, s_all
    return params, model, score


def best_extension(
    ctx: Context,
    cands: Sequence[tuple[dict[str, Any], Callable[[Dataset], Model]]],
    description: str,
) -> Extension | None:
    """:meth:`Context.extension` of :func:`select_pairs`' choice."""
    params, model, score = select_pairs(ctx, cands)
    return ctx.extension(params, model, score, description)
