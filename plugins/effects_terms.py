"""Built-in effects that extend a model with nonlinear terms of its past outputs.

- ``coulomb_friction``: ``tanh(Δ_m y[k-1] / ε)`` per output — a smoothed sign of the velocity;
- ``nonlinear_stiffness``: odd powers ``y[k-1]^3`` (and ``^5``) per output;
- ``gravity``: a constant (operating-point load) and ``cos(y[k-1])`` for angle outputs.

Each effect proposes a few structures and scales, chooses one on the inner split of the
training data (:meth:`tendonkit.diagnose.Context.select`) and refits on all training data with
:func:`tendonkit.augment.extend_with_terms`, which works for every representation.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from tendonkit.augment import extend_with_terms
from tendonkit.dataset import Dataset
from tendonkit.diagnose import Context, Extension
from tendonkit.hookspecs import hookimpl
from tendonkit.residuals import ResidualAnalysis
from tendonkit.schema import Model
from tendonkit.terms import Factor, Term


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def _velocity(y: np.ndarray, m: int) -> np.ndarray:
    v = np.zeros_like(y)
    v[m:] = y[m:] - y[:-m]
    return v


class _TermEffect:
    """Shared logic: candidates of term sets, selection on the check part, refit."""

    name = ""
    cause = ""
    description = ""

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        raise NotImplementedError

    def extend(self, ctx: Context) -> Extension | None:
        """Choose the best term set on the inner split and refit on all training data."""
        cands = self.candidates(ctx)
        if not cands:
            return None

        def builder(terms: list[Term]) -> Callable[[Dataset], Model]:
            return lambda d: extend_with_terms(ctx.baseline, d, terms, refit=ctx.refit)

        params, model, score, _ = ctx.select((p, builder(t)) for p, t in cands)
        if model is None:
            return None
        terms = next(t for p, t in cands if p == params)
        return Extension(
            model=model,
            params={**params, "terms": [t.label for t in terms]},
            description=self.description,
            train_gain=score - ctx.baseline_score,
        )


class CoulombFriction(_TermEffect):
    """Coulomb (dry) friction: a force of constant size opposing the direction of motion."""

    name = "coulomb_friction"
    cause = "coulomb_friction"
    description = (
        "Coulomb friction: adds tanh(velocity/ε) of every output (a smoothed sign of the "
        "direction of motion), with a constant for asymmetric friction (Fc+ ≠ Fc-)."
    )

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        out = []
        y = ctx.train.y
        for m in (1, 3, 8, 20):
            if 4 * m >= min(e.n_samples for e in ctx.train.experiments):
                continue
            vel = np.abs(_velocity(y, m))
            for q in (0.01, 0.05, 0.2):
                eps = np.quantile(vel, q, axis=0)
                eps = np.where(eps > 0, eps, np.max(vel, axis=0) * 1e-3 + 1e-12)
                terms = [
                    Term((Factor(name, fn="tanh", lag=1, diff=m, scale=float(1.0 / eps[j])),))
                    for j, name in enumerate(ctx.train.outputs)
                ]
                params = {"velocity_span": m, "epsilon": [float(e) for e in eps]}
                out.append(({**params, "asymmetric": False}, terms))
                # Asymmetric friction: sign term plus a constant (the EMPS drive needs it).
                out.append(({**params, "asymmetric": True}, [*terms, Term()]))
        return out

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the validation residual with the direction of motion."""
        y = valid.y
        corr = {
            n: _corr(res.residual[:, j], np.sign(_velocity(y[:, j], 3)))
            for j, n in enumerate(valid.outputs)
        }
        rev = {
            c.output: c.ratio for c in res.concentration if c.condition == "near velocity reversals"
        }
        return {
            "statistic": "corr(residual, sign(velocity))",
            "value": corr,
            "reversal_concentration": rev,
            "signal": "sign of the output velocity",
        }


class NonlinearStiffness(_TermEffect):
    """Amplitude-dependent stiffness: hardening or softening springs (Duffing-type)."""

    name = "nonlinear_stiffness"
    cause = "nonlinear_stiffness"
    description = (
        "Nonlinear stiffness: adds odd powers y^3 (and y^5) of every output, a hardening or "
        "softening spring."
    )

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        y = ctx.train.y
        mu = y.mean(axis=0)
        sd = np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)
        outs = []
        for powers in ((3,), (3, 5)):
            terms = [
                Term((Factor(name, power=p, lag=1, scale=float(1 / sd[j]), offset=float(mu[j])),))
                for p in powers
                for j, name in enumerate(ctx.train.outputs)
            ]
            outs.append(({"powers": list(powers)}, terms))
        return outs

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the residual with the part of y^3 that is not linear in y."""
        out = {}
        for j, n in enumerate(valid.outputs):
            y = valid.y[:, j] - valid.y[:, j].mean()
            cube = y**3
            cube = cube - np.dot(cube, y) / max(np.dot(y, y), 1e-300) * y
            out[n] = _corr(res.residual[:, j], cube)
        large = {c.output: c.ratio for c in res.concentration if c.condition == "large |output|"}
        return {
            "statistic": "corr(residual, y^3 ⟂ y)",
            "value": out,
            "large_output_concentration": large,
            "signal": "cube of the output",
        }


class Gravity(_TermEffect):
    """Gravity: a constant load that shifts the operating point, varying with the angle."""

    name = "gravity"
    cause = "gravity"
    description = (
        "Gravity: adds a constant load and, for angle outputs, cos(y) of every output (the "
        "angle-dependent part of a weight's torque)."
    )

    def candidates(self, ctx: Context) -> list[tuple[dict[str, Any], list[Term]]]:
        const = [Term()]
        cands: list[tuple[dict[str, Any], list[Term]]] = [({"terms": "constant"}, const)]
        y = ctx.train.y
        if np.all(np.abs(y) < 2 * np.pi):  # plausible angles in radians
            # cos is even: it models the angle-dependent weight without mimicking the odd,
            # amplitude-dependent terms of a nonlinear stiffness (sin y = y - y^3/6 would).
            cos_terms = [Term((Factor(n, fn="cos", lag=1),)) for n in ctx.train.outputs]
            cands.append(({"terms": "constant+cos"}, const + cos_terms))
        return cands

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Mean of the residual relative to its spread (a static offset)."""
        r = res.residual
        return {
            "statistic": "mean(residual) / std(residual)",
            "value": {
                n: float(r[:, j].mean() / (r[:, j].std() + 1e-300))
                for j, n in enumerate(valid.outputs)
            },
            "signal": "operating point (mean output)",
        }


@hookimpl
def tendonkit_register_effects(registry):  # type: ignore[no-untyped-def]
    """Register the term-based effects."""
    registry.add(CoulombFriction())
    registry.add(NonlinearStiffness())
    registry.add(Gravity())
