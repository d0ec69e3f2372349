"""The results of a diagnosis (:class:`Finding`, :class:`Diagnosis`) and how ties are stated.

Split from :mod:`tendonkit.diagnose`, which re-exports every public name here.  A tie between
the named cause and a runner-up of another cause is stated with the experiment that would
separate the two (:data:`DISCRIMINATING`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..schema import Model
from .residuals import ResidualAnalysis
from .stats import loss_test

FloatArray = NDArray[np.float64]

#: Experiments that separate two causes that explain the data about equally.
DISCRIMINATING: dict[frozenset[str], str] = {
    frozenset({"coulomb_friction", "backlash"}): (
        "slow triangle waves at two or three amplitudes and speeds: backlash leaves a dead band "
        "of the same width after every reversal whatever the amplitude, speed and load; Coulomb "
        "friction leaves a jump whose size follows the friction force and the load."
    ),
    frozenset({"coulomb_friction", "hysteresis"}): (
        "sinusoids of one amplitude at several frequencies and of several amplitudes at one "
        "frequency: Coulomb friction adds a constant-size force at every reversal, hysteresis a "
        "loop whose width scales with the amplitude of the input."
    ),
    frozenset({"backlash", "hysteresis"}): (
        "small-amplitude sinusoids below the suspected play: backlash passes nothing until the "
        "gap is crossed, hysteresis still transmits a (lagged) response."
    ),
    frozenset({"input_delay", "actuator_lag"}): (
        "steps and a swept sine: a delay shifts the whole step response without changing its "
        "shape and its phase grows without bound with frequency; an actuator lag rounds the onset "
        "of the step and its phase levels off (90° for a first-order lag)."
    ),
    frozenset({"dead_zone", "saturation"}): (
        "the same excitation at a small and a large amplitude: a dead zone suppresses the small "
        "inputs and leaves the large ones, saturation clips only the large ones."
    ),
    frozenset({"nonlinear_stiffness", "gravity"}): (
        "the same excitation with the robot mounted in another orientation (or with the bias of "
        "the excitation reversed): gravity shifts the operating point and the sag with the "
        "orientation; a nonlinear stiffness is symmetric and does not depend on it."
    ),
    frozenset({"nonlinear_stiffness", "saturation"}): (
        "a slow ramp to large amplitude: saturation flattens the response at a level, a "
        "hardening or softening stiffness keeps changing the slope smoothly."
    ),
    frozenset({"dead_zone", "backlash"}): (
        "a slow triangle wave: a dead zone on an input is symmetric about its centre and has no "
        "memory; backlash depends on the direction of motion (a loop, not a flat band)."
    ),
}

DEFAULT_EXPERIMENT = (
    "repeat the experiment at two excitation amplitudes and two speeds: the candidate causes "
    "scale differently with amplitude (static nonlinearities), speed (dynamics) and direction "
    "(memory effects)."
)


# -- results --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Finding:
    """One candidate cause and what it achieved on the validation data."""

    cause: str
    effect: str
    gain: float
    fit: dict[str, float]
    relative_gain: float
    p_value: float
    significant: bool
    params: dict[str, Any]
    evidence: dict[str, Any]
    description: str
    model: Model | None = None
    n_params: int = 0
    p_adjusted: float = 1.0
    test: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (without the model)."""
        return {
            "n_params": self.n_params,
            "cause": self.cause,
            "effect": self.effect,
            "gain": self.gain,
            # a candidate whose simulation diverged has no gain (written as null in JSON)
            "diverged": not math.isfinite(self.gain),
            "fit": self.fit,
            "relative_gain": self.relative_gain,
            "p_value": self.p_value,
            "p_adjusted": self.p_adjusted,
            "significant": self.significant,
            "test": self.test,
            "params": self.params,
            "evidence": self.evidence,
            "description": self.description,
        }


@dataclass(frozen=True)
class Diagnosis:
    """The outcome of :func:`diagnose`."""

    cause: str
    baseline_method: str
    baseline: Model
    baseline_fit: dict[str, float]
    findings: tuple[Finding, ...]
    residuals: ResidualAnalysis
    ambiguous: dict[str, Any] | None
    settings: dict[str, Any]
    skipped: tuple[dict[str, str], ...] = ()
    named_effect: str | None = None
    #: The check of the requested baseline against a linear N4SID reference
    #: (:func:`check_baseline`); ``fallback`` says whether N4SID replaced it.
    baseline_check: dict[str, Any] | None = None
    #: Why the baseline cannot be diagnosed (its validation fit is not above 0 %), or None.
    unfit: str | None = None

    @property
    def best(self) -> Finding | None:
        """The finding that names the cause (None when the cause is ``none``)."""
        if self.cause == "none":
            return None
        if self.named_effect is not None:
            return next((f for f in self.findings if f.effect == self.named_effect), None)
        sig = [f for f in self.findings if f.significant]
        return sig[0] if sig else None

    @property
    def extended(self) -> Model:
        """The extended model of the named cause, or the baseline when the cause is ``none``."""
        best = self.best
        return best.model if best is not None and best.model is not None else self.baseline

    @property
    def extended_fit(self) -> dict[str, float]:
        """Validation fit of :attr:`extended`."""
        best = self.best
        return best.fit if best is not None else self.baseline_fit

    def to_dict(self, model_path: str | None = None) -> dict[str, Any]:
        """JSON-ready form; ``model_path`` is where the extended model was saved."""
        best = self.best
        return {
            "cause": self.cause,
            "baseline": {
                "method": self.baseline_method,
                "fit": _mean(self.baseline_fit),
                "fit_per_output": self.baseline_fit,
                "check": self.baseline_check,
                "unfit": self.unfit,
            },
            "extended": {
                "fit": _mean(self.extended_fit),
                "fit_per_output": self.extended_fit,
                "gain": best.gain if best else 0.0,
                "effect": best.effect if best else None,
                "params": best.params if best else {},
                "model": model_path,
            },
            "named_effect": best.effect if best else None,
            "margin_to_runner_up": self.margin,
            "runner_up": self.runner_up.cause if self.runner_up else None,
            "ambiguous": self.ambiguous,
            "findings": [f.to_dict() for f in self.findings],
            "skipped": list(self.skipped),
            "residuals": self.residuals.to_dict(),
            "settings": self.settings,
        }

    @property
    def margin(self) -> float | None:
        """Gain of the named finding minus the best gain of another cause (points)."""
        best = self.best
        if best is None:
            return None
        others = [f.gain for f in self.findings if f.cause != best.cause]
        return best.gain - max(others) if others else None

    @property
    def runner_up(self) -> Finding | None:
        """The finding of another cause with the largest gain."""
        best = self.best
        if best is None:
            return None
        return next((f for f in self.findings if f.cause != best.cause), None)


def evidence_notes(summary: dict[str, Any]) -> list[str]:
    """Sentences on how the named cause was established, from :meth:`Diagnosis.to_dict`.

    Said when it matters: the cause was seen in the data by the effect's direct test (then
    the fit gain alone may not be significant), or a finding of another cause gains more on
    the validation data without being significant.
    """
    named = summary.get("named_effect")
    findings = summary.get("findings", [])
    best = next((f for f in findings if f["effect"] == named), None)
    if best is None:
        return []
    notes = []
    direct = best.get("test", {}).get("direct")
    if direct:
        notes.append(
            "seen in the data"
            + (f": {what}" if (what := direct.get("summary") or direct.get("statistic")) else "")
            + f" (p = {direct['p_value']:.2g}); the fit gain alone: "
            f"p = {best['test']['loss_p_value']:.2g} (before the adjustment for trying every "
            "effect)."
        )
    larger = [f for f in findings if f["cause"] != best["cause"] and f["gain"] > best["gain"]]
    if larger:
        top = larger[0]
        p_adj = top.get("p_adjusted", top["p_value"])
        if top["significant"]:
            notes.append(
                f"{top['cause']} gains more ({top['gain']:+.2f} points, p_adj = {p_adj:.2g}) "
                f"with more parameters ({top['n_params']} against {best['n_params']}) and is "
                f"not significantly better: the simpler {best['cause']} is named."
            )
        else:
            notes.append(
                f"{top['cause']} gains more ({top['gain']:+.2f} points) but is not significant "
                f"(p_adj = {p_adj:.2g}): a possible second effect, not shown by these data."
            )
    return notes


def _mean(d: dict[str, float]) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


def _ambiguity(
    findings: list[Finding],
    best: Finding,
    losses: dict[str, FloatArray],
    tie_ratio: float,
    alpha: float,
) -> dict[str, Any] | None:
    """A tie between the named cause and the best significant finding of another cause."""
    b = next((f for f in findings if f.significant and f.cause != best.cause), None)
    if b is None:
        return None
    a = best
    test = loss_test(losses[b.effect], losses[a.effect])
    close = b.gain >= tie_ratio * a.gain or test.p_value >= alpha
    if not close:
        return None
    return {
        "between": [a.cause, b.cause],
        "gains": [a.gain, b.gain],
        "p_value": test.p_value,
        "statement": (
            f"{a.cause} (gain {a.gain:.2f}) and {b.cause} (gain {b.gain:.2f}) explain these data "
            f"about equally well (one-sided p = {test.p_value:.3g} that {a.cause} is better)."
        ),
        "experiment": DISCRIMINATING.get(frozenset({a.cause, b.cause}), DEFAULT_EXPERIMENT),
    }
