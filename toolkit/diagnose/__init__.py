"""Find what a model's simulation gets wrong, name the cause, extend the model, measure the gain.

The door of the diagnose room.  For users: :func:`diagnose` and its results (:class:`Diagnosis`,
:class:`Finding`).  For effect plugins: the contract (:class:`Effect`, the optional
:class:`DirectTest`, the :class:`Context` an effect receives and the :class:`Extension` it
returns) and the tools built-in effects use to build and check extensions (refits with added
terms or blocks, the residual analysis, the clip detector, simulation of a whole dataset).

Behind the door: ``engine`` (the procedure), ``effect`` (the contract), ``residuals`` (what the
errors show), ``stats`` (the loss test and Holm), ``clip`` (the clip detector), ``extend``
(refitting a model with added terms or blocks), ``findings`` (results and ties) and ``report``
(the HTML report).
"""

from __future__ import annotations

from .clip import AtomTest, atom_test
from .effect import (
    Context,
    DirectTest,
    Effect,
    Extension,
    added_parameters,
    mean_fit,
    simulate_all,
)
from .engine import BIAS_RATIO, check_baseline, diagnose, params_of
from .extend import (
    drop_samples,
    extend_with_terms,
    fit_wiener,
    refit_with_input_blocks,
    transform_inputs,
    transform_outputs,
    with_output_curves,
)
from .findings import DEFAULT_EXPERIMENT, DISCRIMINATING, Diagnosis, Finding, Step
from .residuals import ResidualAnalysis

__all__ = [
    "BIAS_RATIO",
    "DEFAULT_EXPERIMENT",
    "DISCRIMINATING",
    "AtomTest",
    "Context",
    "Diagnosis",
    "DirectTest",
    "Effect",
    "Extension",
    "Finding",
    "ResidualAnalysis",
    "Step",
    "added_parameters",
    "atom_test",
    "check_baseline",
    "diagnose",
    "drop_samples",
    "extend_with_terms",
    "fit_wiener",
    "mean_fit",
    "params_of",
    "refit_with_input_blocks",
    "simulate_all",
    "transform_inputs",
    "transform_outputs",
    "with_output_curves",
]
