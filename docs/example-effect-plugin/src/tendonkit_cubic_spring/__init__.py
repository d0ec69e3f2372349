"""An example effect plugin for ``tendonkit diagnose``: a hardening cubic spring.

A spring that stiffens as it stretches pulls back with ``k y + k3 y³``; a linear model can only
represent the ``k y``.  This effect adds the term ``y³`` of every output (read one sample back,
centred and scaled by the output's spread) to the baseline and lets ``diagnose`` test it on the
validation data.  Its cause, from the fixed vocabulary, is ``nonlinear_stiffness``.

Everything an effect needs comes through the door :mod:`tendonkit.diagnose`: the contract
(:class:`~tendonkit.diagnose.Effect`, :class:`~tendonkit.diagnose.Context`,
:class:`~tendonkit.diagnose.Extension`) and the refit with added terms
(:func:`~tendonkit.diagnose.extend_with_terms`).  No base class, no change to tendonkit: the
entry point in ``pyproject.toml`` is the whole registration.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tendonkit import hookimpl
from tendonkit.dataset import Dataset
from tendonkit.diagnose import Context, Extension, ResidualAnalysis, extend_with_terms
from tendonkit.schema import Model
from tendonkit.terms import Factor, Term


class CubicSpring:
    """The effect: ``name``, ``cause``, ``extend`` and ``signature`` (the Effect protocol)."""

    name = "cubic_spring"
    cause = "nonlinear_stiffness"
    description = "Cubic spring: adds y³ of every output (a hardening or softening spring)."

    def extend(self, ctx: Context) -> Extension | None:
        """The baseline refitted with ``y³`` terms on the training data only."""
        y = ctx.train.y
        mu, sd = y.mean(axis=0), np.where(y.std(axis=0) > 0, y.std(axis=0), 1.0)
        terms = [
            Term((Factor(name, power=3, lag=1, scale=float(1 / sd[j]), offset=float(mu[j])),))
            for j, name in enumerate(ctx.train.outputs)
        ]

        def build(data: Dataset) -> Model:
            return extend_with_terms(ctx.baseline, data, terms, note="cubic spring")

        return ctx.best_extension([({"power": 3}, build)], self.description)

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Correlation of the validation residual with the cube of the output (for the report)."""
        value = {
            n: float(
                np.corrcoef(res.residual[:, j], (valid.y[:, j] - valid.y[:, j].mean()) ** 3)[0, 1]
            )
            for j, n in enumerate(valid.outputs)
        }
        return {"statistic": "corr(residual, y³)", "value": value, "signal": "cube of the output"}


@hookimpl
def tendonkit_register_effects(registry: Any) -> None:
    """Register the effect (pluggy calls this through the ``tendonkit`` entry point)."""
    registry.add(CubicSpring())
