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
from .stats import BATCH_TAUS, MAX_BATCHES, obm_dof, routes_p_value

FloatArray = NDArray[np.float64]

#: The routes of the significance test's loss comparison, in the order every caller passes
#: them (``tendonkit.diagnose.engine.try_effect``): the free run, the one-step prediction,
#: the prediction over ``prediction_horizon`` samples.
ROUTES = ("simulation", "prediction", "horizon")

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
    frozenset({"static_nonlinearity", "nonlinear_stiffness"}): (
        "a swept sine at one amplitude and the same sweep at a larger one: a static curve on the "
        "signal path distorts the response at every frequency alike, a nonlinear stiffness "
        "shifts the resonance with the amplitude (and jumps near it)."
    ),
    frozenset({"static_nonlinearity", "saturation"}): (
        "a slow ramp through the whole range: saturation is flat beyond a level, a static curve "
        "keeps bending (and may be asymmetric or non-monotone, as a rectifier)."
    ),
    frozenset({"static_nonlinearity", "dead_zone"}): (
        "a slow ramp through zero: a dead zone passes nothing inside its band and is linear "
        "outside it, a static curve bends everywhere."
    ),
    frozenset({"static_nonlinearity", "hysteresis"}): (
        "a slow triangle wave: a static curve gives the same output going up and down, "
        "hysteresis a loop."
    ),
    frozenset({"dead_zone", "backlash"}): (
        "a slow triangle wave: a dead zone on an input is symmetric about its centre and has no "
        "memory; backlash depends on the direction of motion (a loop, not a flat band)."
    ),
}

#: Causes that are special cases of a more general one: when the general one gains most, a
#: significant special case is named instead (it says more: a clip at a level, a band of a
#: width), and the general one's extra gain is reported beside it.
SPECIAL_CASES: dict[str, tuple[str, ...]] = {
    "static_nonlinearity": ("saturation", "dead_zone"),
}

#: Causes whose extensions, on one path, only reshape what the other named: a general
#: memoryless curve and its special cases (:data:`SPECIAL_CASES`), and a hysteretic force of the
#: outputs and Coulomb friction on them — the play's elastic-plastic force ``k·(y - play(y))``
#: with its elastic range shrunk to zero at ``k·w = F_c`` is ``F_c·sign(ẏ)``.  A later step of
#: the sequence does not try such a reshape of a cause already named (docs/diagnose.md, step 8).
RESHAPING: dict[str, tuple[str, ...]] = {
    **SPECIAL_CASES,
    "hysteresis": ("coulomb_friction",),
}


def reshaping_paths(cause: str, params: dict[str, Any]) -> frozenset[str]:
    """Where an extension of ``cause`` acts, for the causes :data:`RESHAPING` relates: a curve
    on the ``"inputs"`` or the ``"outputs"``, or a ``"force on the outputs"`` (hysteresis, and
    friction by the sign of the output's velocity or of a speed output; a friction played in
    force space acts on the inputs), or a ``"force between <outputs>"`` for the same two
    causes between two bodies (plugins/_bodies.py: their path is the pair, not each output).
    Empty for any other cause or an unknown structure."""
    structure = str(params.get("structure"))
    between = params.get("between")
    if between and cause in ("hysteresis", "coulomb_friction"):
        # a force between two bodies (the difference of two outputs), not on each output
        return frozenset({f"force between {between}"})
    if cause == "static_nonlinearity":
        return {
            "Hammerstein": frozenset({"inputs"}),
            "Wiener": frozenset({"outputs"}),
            # the curve between two filters acts on the (filtered) input path
            "Wiener-Hammerstein": frozenset({"inputs"}),
        }.get(structure, frozenset())
    if cause == "dead_zone":
        return frozenset({"inputs"})
    if cause == "saturation":
        return frozenset({"outputs" if params.get("where") == "output" else "inputs"})
    if cause == "hysteresis":
        return frozenset({"force on the outputs"})
    if cause == "coulomb_friction" and structure.startswith("sign of"):
        return frozenset({"force on the outputs"})
    return frozenset()


def reshapes(cause: str, params: dict[str, Any], named: str, named_params: dict[str, Any]) -> bool:
    """Whether an extension of ``cause`` with ``params`` only reshapes the cause ``named`` (with
    ``named_params``): one is a special case of the other (:data:`RESHAPING`) and they act on
    the same path (:func:`reshaping_paths`)."""
    related = cause in RESHAPING.get(named, ()) or named in RESHAPING.get(cause, ())
    paths = reshaping_paths(cause, params) & reshaping_paths(named, named_params)
    return related and bool(paths)


def between_text(params: dict[str, Any] | None) -> str:
    """``" between y1-y2"`` for an extension acting between two outputs (two bodies,
    plugins/_bodies.py), else ``""``."""
    pair = (params or {}).get("between")
    if not pair:
        return ""
    return f" between {pair if isinstance(pair, str) else ', '.join(map(str, pair))}"


def reshape_reason(cause: str, named: str, index: int) -> str:
    """Why an extension of ``cause`` is not tried after ``named`` was named at step ``index``."""
    why = (
        "a memoryless curve on the same signal path, one curve"
        if cause in SPECIAL_CASES or named in SPECIAL_CASES
        else "a force of the same outputs with a memory (friction is a hysteresis with no "
        "elastic range)"
    )
    return f"{RESHAPES} {named} named at step {index}: {why}, not a second cause"


#: How the reason of an effect left out as a reshape (:func:`reshape_reason`) begins.
RESHAPES = "reshapes the"


def reshaping_notes(step: dict[str, Any]) -> list[str]:
    """``not tested: <effects> (<reason>)`` per reason, for the effects a step of the sequence
    (its JSON form) left out because they reshape a cause named before."""
    groups: dict[str, list[str]] = {}
    for s in step.get("skipped", []):
        if s["reason"].startswith(RESHAPES):
            groups.setdefault(s["reason"], []).append(s["effect"])
    return [f"not tested: {', '.join(names)} ({reason})" for reason, names in groups.items()]


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
class Step:
    """One step of a diagnosis's sequence of causes (:attr:`Diagnosis.steps`).

    Step 1 starts from the baseline, step ``k`` from the model step ``k - 1`` named.  The last
    step is the one where nothing more was significant, or where the cause named was not
    confirmed by the refined models (``cause == "none"``; :attr:`stop` says why), unless the
    sequence stopped at ``max_causes`` or after a named step whose structure could not be
    carried on to the next (its :attr:`stop` says why).
    """

    index: int
    cause: str
    effect: str | None
    #: Validation gain over the model the step started from (points of mean fit).
    gain: float
    fit_before: dict[str, float]
    #: Validation fit of :attr:`model` (refined by simulation error when diagnose refines).
    fit: dict[str, float]
    #: Validation fit of the extension as tested (its equation-error estimate).
    tested_fit: dict[str, float]
    p_adjusted: float | None
    params: dict[str, Any]
    n_params: int
    model: Model | None
    findings: tuple[Finding, ...]
    ambiguous: dict[str, Any] | None
    skipped: tuple[dict[str, str], ...] = ()
    #: Why the sequence stopped after this step, when it was not for lack of evidence.
    stop: str | None = None
    #: Steps after the first: the free-run test of this step's refined model against the
    #: previous step's (``applied``, ``p_value``, ``fit_before``, ``fit_after``, or the
    #: ``reason`` it does not apply; engine.confirm_step).
    confirmation: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (without the model)."""
        return {
            "step": self.index,
            "cause": self.cause,
            "effect": self.effect,
            "gain": self.gain,
            "fit_before": _mean(self.fit_before),
            "fit": _mean(self.fit),
            "tested_fit": _mean(self.tested_fit),
            "p_adjusted": self.p_adjusted,
            "params": self.params,
            "n_params": self.n_params,
            "ambiguous": self.ambiguous,
            "stop": self.stop,
            "confirmation": self.confirmation,
            "findings": [f.to_dict() for f in self.findings],
            "skipped": list(self.skipped),
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
    #: The sequence of causes, step 1 first (empty when the first step named nothing).  Step
    #: 1 is this diagnosis's own :attr:`cause` and :attr:`findings`.
    steps: tuple[Step, ...] = ()
    #: How the baseline chose its structure (``method="auto"``; :func:`auto_baseline`).
    baseline_choice: dict[str, Any] | None = None
    #: Standard deviation of each validation output: the RMSE of a fit ``f`` is
    #: ``(1 - f / 100) · std`` (:meth:`rmse`), in the output's unit.
    output_std: dict[str, float] = field(default_factory=dict)
    #: Another model measured on the same validation data (``diagnose(versus="pem")``: the best
    #: linear model): method, ``fit``, ``fit_per_output`` and its notes; None when not asked.
    versus: dict[str, Any] | None = None

    def _versus(self) -> dict[str, Any] | None:
        if self.versus is None:
            return None
        v = self.versus
        if "fit" not in v:
            return dict(v)
        return {
            **v,
            "rmse_per_output": self.rmse(v["fit_per_output"]),
            "extended_gain": _mean(self.extended_fit) - v["fit"],
        }

    def rmse(self, fits: dict[str, float]) -> dict[str, float]:
        """Validation RMSE per output, in the output's unit, of a model with these fits."""
        return {
            n: (1.0 - f / 100.0) * self.output_std[n]
            for n, f in fits.items()
            if n in self.output_std
        }

    @property
    def causes(self) -> tuple[str, ...]:
        """Every cause named, in the order the sequence named them (``("none",)`` if none)."""
        named = tuple(s.cause for s in self.steps if s.cause != "none")
        return named or (self.cause,)

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
        """The final model: the baseline extended with every cause named (the baseline if none)."""
        last = self._last_named
        if last is not None and last.model is not None:
            return last.model
        best = self.best
        return best.model if best is not None and best.model is not None else self.baseline

    @property
    def extended_fit(self) -> dict[str, float]:
        """Validation fit of :attr:`extended`."""
        last = self._last_named
        if last is not None:
            return last.fit
        best = self.best
        return best.fit if best is not None else self.baseline_fit

    @property
    def _last_named(self) -> Step | None:
        named = [s for s in self.steps if s.cause != "none"]
        return named[-1] if named else None

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
                "choice": self.baseline_choice,
                "rmse_per_output": self.rmse(self.baseline_fit),
                "unfit": self.unfit,
            },
            "causes": list(self.causes),
            "extended": {
                "fit": _mean(self.extended_fit),
                "fit_per_output": self.extended_fit,
                "gain": best.gain if best else 0.0,
                "total_gain": _mean(self.extended_fit) - _mean(self.baseline_fit),
                "rmse_per_output": self.rmse(self.extended_fit),
                "effect": best.effect if best else None,
                "effects": [s.effect for s in self.steps if s.effect]
                if self.steps
                else ([best.effect] if best else []),
                "params": best.params if best else {},
                "model": model_path,
            },
            "versus": self._versus(),
            "sequence": [s.to_dict() for s in self.steps],
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


def _as_tested(contest: dict[str, Any]) -> str:
    """What a contest's gains are where a refined model was refused (its tested one kept),
    and why a special case that gains a little less than its general curve is named."""
    tested = contest.get("kept_as_tested") or []
    its = "their refined models" if len(tested) > 1 else "its refined model"
    out = (
        f" ({' and '.join(tested)} as tested: {its} simulated the validation data worse or "
        "could not be computed)"
        if tested
        else ""
    )
    gains, named = contest.get("refined_gains", {}), contest.get("named")
    other = next((e for e in contest.get("between", []) if e != named), None)
    if named in gains and other in gains and gains[named] < gains[other]:
        out += (
            "; the general curve gains no more than min_gain more, which does not earn its extra "
            "parameters"
        )
    return out


def runner_up_text(summary: dict[str, Any]) -> str:
    """`` (cause, not significant)``: which finding the margin to the runner-up is measured
    to, from :meth:`Diagnosis.to_dict` (empty without one).  A runner-up that is not
    significant can gain more than the named cause (the margin is then negative)."""
    cause = summary.get("runner_up")
    top = next((f for f in summary.get("findings", []) if f["cause"] == cause), None)
    if top is None:
        return ""
    return f" ({cause}{'' if top['significant'] else ', not significant'})"


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
        min_gain = float((summary.get("settings") or {}).get("min_gain", 0.0))
        top = next(
            (
                f
                for f in findings
                if not f["significant"]
                and isinstance(f["gain"], int | float)
                and f["gain"] >= min_gain
            ),
            None,
        )
        if top is None:
            return []
        more = _more_data(top, summary)
        if not more:
            return []
        return [
            f"{top['cause']} gains {top['gain']:+.2f} points but is not significant "
            f"(p_adj = {top.get('p_adjusted', top['p_value']):.2g})" + more + "."
        ]
    notes = []
    explains = best.get("test", {}).get("explains")
    if explains:
        notes.append(
            f"the baseline alone does not explain the validation data (fit "
            f"{explains['baseline_fit']:.1f} %, no better than their mean); with "
            f"{best['cause']} the model does ({explains['extended_fit']:.1f} %), and it closes "
            f"{explains['training_gain']:.1f} of the baseline's {explains['training_misfit']:.1f} "
            "points of misfit on the training data: the cause is what the baseline lacked."
        )
    direct = best.get("test", {}).get("direct")
    if direct:
        notes.append(
            "seen in the data"
            + (f": {what}" if (what := direct.get("summary") or direct.get("statistic")) else "")
            + f" (p = {direct['p_value']:.2g}); the fit gain alone: "
            f"p = {best['test']['loss_p_value']:.2g} (before the adjustment for trying every "
            "effect)."
        )
    contest = best.get("test", {}).get("contest")
    told = False  # the contest's gains are said once
    if contest and not best["significant"]:
        # the contest record lists the general cause first
        general = next((f for f in findings if f["effect"] == contest["between"][0]), None)
        if general is not None:
            told = True
            notes.append(
                f"not significant on its own (p_adj = "
                f"{best.get('p_adjusted', best['p_value']):.2g}), but {general['cause']} is "
                f"(p_adj = {general.get('p_adjusted', general['p_value']):.2g}): a static curve "
                f"is there, and refined by simulation error its shape as {best['cause']} gains "
                f"{contest['refined_gains'][best['effect']]:+.2f} points against the general "
                f"curve's {contest['refined_gains'][general['effect']]:+.2f}"
                + _as_tested(contest)
                + "."
            )
    held = best.get("test", {}).get("held_out") or {}
    decided = "p_route" in held and held["p_route"] * best["test"].get("routes", 1) <= (
        best["p_value"] * (1 + 1e-9)
    )
    if "folds" in held and decided:
        notes.append(
            f"shown on held-out blocks of the training data ({held['folds']} folds, "
            f"{held['samples']} samples; p = {held['p_value']:.2g}); the validation record is "
            f"{best['test']['n_batches']} batches of {best['test']['batch_length']} samples "
            f"against an autocorrelation time of {best['test']['tau']:.0f}, and its free run "
            f"alone gives p = {best['test']['p_value']:.2g} (before the adjustment for trying "
            "every effect)."
        )
    larger = [f for f in findings if f["cause"] != best["cause"] and f["gain"] > best["gain"]]
    if larger:
        top = larger[0]
        p_adj = top.get("p_adjusted", top["p_value"])
        if told and top["effect"] == contest["between"][0]:
            pass  # the note above compared the two
        elif top["significant"] and best["cause"] in SPECIAL_CASES.get(top["cause"], ()):
            why = (
                f"refined by simulation error, it gains "
                f"{contest['refined_gains'][best['effect']]:+.2f} points against "
                f"{contest['refined_gains'][top['effect']]:+.2f}" + _as_tested(contest)
                if contest
                else "it is seen in the data, or the models were not refined"
            )
            notes.append(
                f"{top['cause']} gains more as fitted ({top['gain']:+.2f} points, p_adj = "
                f"{p_adj:.2g}); {best['cause']}, a special case of it, is named: {why}."
            )
        elif top["significant"]:
            notes.append(
                f"{top['cause']} gains more ({top['gain']:+.2f} points, p_adj = {p_adj:.2g}) "
                f"with more parameters ({top['n_params']} against {best['n_params']}) and is "
                f"not significantly better: the simpler {best['cause']} is named."
            )
        else:
            notes.append(
                f"{top['cause']} gains more ({top['gain']:+.2f} points) but is not significant "
                f"(p_adj = {p_adj:.2g}): a possible second effect, not shown by these data"
                + _more_data(top, summary)
                + "."
            )
    return notes


#: Largest multiple of the validation data :func:`more_data_factor` puts a number on.
MORE_DATA_CAP = 20.0


def more_data_factor(finding: dict[str, Any], alpha: float, n_findings: int) -> float | None:
    """Roughly how many times as much validation data would make this finding significant.

    For each loss route the test kept (free run, one-step prediction, prediction over the
    horizon; ``routes_screened``) the one-sided t-statistic of the batch log-ratios,
    ``t = (mean + log(1 - margin)) / std_error``, grows with the square root of the
    record's length if the gain holds.  A record ``K`` times as long has
    ``clip(K·n / (4 τ), 5, 50)`` batches (:func:`tendonkit.diagnose.stats.loss_test`; the
    degrees of freedom of :func:`tendonkit.diagnose.stats.obm_dof`), and needs ``t·√K`` above
    the t quantile of the route's share of the level after the Holm
    adjustment (read from the finding's p-value and adjusted p-value; a capped adjustment
    counts every finding).  A route on which the extension's linear part decides
    (``test.linear_part``) is left out: more data against the baseline would not help.  The
    smallest such ``K`` on a grid up to :data:`MORE_DATA_CAP`, over the routes; ``inf`` above
    it, None when no route points the right way.  An estimate
    that assumes the gain and the errors' autocorrelation stay as they are.
    """
    # lazy: heavy (scipy), only when a note is written
    from scipy import stats

    test = finding.get("test") or {}
    beyond = test.get("linear_part") or {}
    kept = (test.get("routes_screened") or {}).get("kept", ROUTES)
    routes = []
    counted = 0  # routes in the test's Bonferroni factor, whether or not they can gain
    for name in ROUTES:
        if name not in kept:  # the training screen left it out of the test
            continue
        r = test if name == "simulation" else (test.get(name) or {})
        counted += bool(r)
        # a route on which the extension's linear part decides gains nothing from more data
        if float(beyond.get(name, 0.0)) > float(r.get("p_value", 1.0)):
            continue
        values = [r.get(k) for k in ("std_error", "log_ratio", "n_batches", "tau")]
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in values):
            continue
        se, mean, nb, tau = (float(v) for v in values)  # type: ignore[arg-type]
        if se <= 0 or nb < 2:
            continue
        t = (mean + math.log(1.0 - float(r.get("margin", test.get("margin", 0.0))))) / se
        routes.append((t, int(nb) * int(r.get("batch_length", 1)), tau))
    if not any(t > 0 for t, _, _ in routes):
        return None
    # the test's own Bonferroni factor (routes the training screen dropped do not count;
    # the held-out route and direct evidence do); older summaries lack it
    k = int(test.get("routes") or counted + (1 if test.get("direct") else 0))
    p, p_adj = float(finding.get("p_value", 1.0)), float(finding.get("p_adjusted", 1.0))
    holm = p_adj / p if 0 < p and p_adj < 1.0 else float(max(n_findings, 1))
    level = alpha / (max(holm, 1.0) * max(k, 1))
    for factor in np.geomspace(1.0, MORE_DATA_CAP, 61):
        for t, n, tau in routes:
            longer = int(factor * n)
            batches = int(np.clip(longer // max(math.ceil(BATCH_TAUS * tau), 1), 5, MAX_BATCHES))
            dof = obm_dof(longer, longer // batches, BATCH_TAUS * tau)
            if t * math.sqrt(factor) >= stats.t.ppf(1.0 - level, dof):
                return float(factor)
    return math.inf


def _more_data(finding: dict[str, Any], summary: dict[str, Any]) -> str:
    alpha = float((summary.get("settings") or {}).get("alpha", 0.01))
    factor = more_data_factor(finding, alpha, len(summary.get("findings", [])))
    if factor is None:
        return ""
    if factor > MORE_DATA_CAP:
        return f"; even {MORE_DATA_CAP:.0f} times as much validation data would hardly show it"
    return (
        f"; about {factor:.1f} times as much validation data would show it if the gain holds "
        "(an estimate from its test statistic)"
    )


def experiment_lead(ambiguous: dict[str, Any]) -> str:
    """How a tie's experiment is introduced: to confirm a tie the data decided, or to tell
    the two apart."""
    return "to confirm it" if ambiguous.get("decided") else "to tell them apart"


def _mean(d: dict[str, float]) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


def tie_runner_up(
    findings: list[Finding],
    best: Finding,
    losses: dict[str, tuple[FloatArray | None, ...]],
    tie_ratio: float,
    alpha: float,
) -> Finding | None:
    """The best significant finding of another cause, if it ties with the named one: its gain
    is at least ``tie_ratio`` of the named one's, or the named one is not significantly better."""
    b = next((f for f in findings if f.significant and f.cause != best.cause), None)
    if b is None:
        return None
    if b.gain >= tie_ratio * best.gain:
        return b
    return b if routes_p_value(losses[b.effect], losses[best.effect]) >= alpha else None


def _ambiguity(
    findings: list[Finding],
    best: Finding,
    losses: dict[str, tuple[FloatArray | None, ...]],
    tie_ratio: float,
    alpha: float,
) -> dict[str, Any] | None:
    """A tie between the named cause and the best significant finding of another cause."""
    b = tie_runner_up(findings, best, losses, tie_ratio, alpha)
    if b is None:
        return None
    a = best
    p_value = routes_p_value(losses[b.effect], losses[a.effect])
    if b.gain > a.gain:
        statement = (
            f"{b.cause} gains more than the named {a.cause} ({b.gain:.2f} against {a.gain:.2f} "
            f"points) and is significant too: both may be at work, or one stands in for the "
            f"other (one-sided p = {p_value:.3g} that {a.cause} is better)."
        )
    elif p_value < alpha and a.gain > 0:
        # a tie by the size of the gains alone: the test says the named one is better, and
        # the statement must not say "equally well" beside that p-value
        statement = (
            f"{a.cause} (gain {a.gain:.2f}) explains these data better than {b.cause} (gain "
            f"{b.gain:.2f}; one-sided p = {p_value:.3g} that {a.cause} is better), but the "
            f"gains are close ({b.gain / a.gain:.0%}): both may be at work, or one stands in "
            "for the other."
        )
    else:
        statement = (
            f"{a.cause} (gain {a.gain:.2f}) and {b.cause} (gain {b.gain:.2f}) explain these data "
            f"about equally well (one-sided p = {p_value:.3g} that {a.cause} is better)."
        )
    enc = a.test.get("encompassing") or {}
    decided = False
    if enc.get("over") == b.effect:
        statement += (
            f" With {a.cause} in the model, {b.cause} gains {enc['its_gain_after']:+.2f} points; "
            f"with {b.cause} in it, {a.cause} gains {enc['gain_after_it']:+.2f}"
        )
        decided = bool(enc.get("encompasses"))
        statement += (
            f": the data decide for {a.cause}, which accounts for what {b.cause} explains."
            if decided
            else f": neither accounts for the other (the smallest gain that counts is "
            f"{enc['min_gain']:g} points)."
        )
    return {
        "between": [a.cause, b.cause],
        "gains": [a.gain, b.gain],
        "p_value": p_value,
        "decided": decided,
        "statement": statement,
        "experiment": DISCRIMINATING.get(frozenset({a.cause, b.cause}), DEFAULT_EXPERIMENT),
    }
