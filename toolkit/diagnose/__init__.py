"""Find what a model's simulation gets wrong, name the cause, extend the model, measure the gain.

The door of the diagnose room: :func:`diagnose` and its results (:class:`Diagnosis`,
:class:`Finding`), and what an effect plugin receives (:class:`Context`) and returns
(:class:`Extension`).  The modules behind it: ``engine`` (the procedure), ``residuals`` (what
the errors show), ``stats`` (the tests), ``extend`` (refitting a model with added terms or
blocks), ``findings`` (results and ties) and ``report`` (the HTML report).
"""

from __future__ import annotations

from .engine import (
    BIAS_RATIO,
    DEFAULT_EXPERIMENT,
    DISCRIMINATING,
    Context,
    Diagnosis,
    Extension,
    Finding,
    added_parameters,
    check_baseline,
    diagnose,
    mean_fit,
    params_of,
)

__all__ = [
    "BIAS_RATIO",
    "DEFAULT_EXPERIMENT",
    "DISCRIMINATING",
    "Context",
    "Diagnosis",
    "Extension",
    "Finding",
    "added_parameters",
    "check_baseline",
    "diagnose",
    "mean_fit",
    "params_of",
]
