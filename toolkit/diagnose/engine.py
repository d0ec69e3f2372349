"""Diagnose: show what a model's simulation gets wrong, name the cause, extend, measure the gain.

The procedure, for any registered identifier as the baseline and any registered effects
(``docs/diagnose.md`` has the reasoning and the calibration):

1. **Baseline.** Identify on the training data; simulate (free run) on the validation data.
   :func:`check_baseline` compares it with a linear N4SID model of the training data; a
   baseline grossly worse than that (an equation-error fit biased by output noise) is
   replaced by N4SID, because extensions would otherwise "gain" by changing the bias.
2. **Residuals.** Analyse where the validation error concentrates and how the one-step
   residuals correlate with the inputs (:mod:`tendonkit.diagnose.residuals`); effects turn this into
   their evidence.
3. **Candidates.** Every effect proposes extensions of the baseline with its own parameters
   (a delay, a dead-zone threshold, a friction term, ...).  Each candidate is fitted on the
   *training* data and the effect keeps the one with the best free-run simulation fit on the
   same training data.  (An inner train/check split was rejected: an effect that shows only
   in part of a record — the tanks overflow early in theirs — is then invisible to the
   selection.)  The validation data are never seen here.
4. **Gain.** Each extended model is simulated on the validation data.  The gain is the change
   in mean fit (percentage points); findings are ranked by it.
5. **Significance.** :func:`loss_test` on the per-sample validation losses: a one-sided
   t-test over contiguous batches (4 integrated autocorrelation times long, 5–50 of them) of
   ``log((1 - δ)·L_base,b / L_ext,b)`` — the extension must remove more than the margin
   ``δ = min_relative_gain`` of the baseline's error energy in a typical stretch of the
   record, and gain at least ``min_gain`` points of fit (an effect size worth naming).  The p-values are Holm-adjusted over the effects tried, weighted by the effects'
   *training* gains (fixed before the validation data are looked at).  Noise alone then
   never names a cause: without structure the batch log-ratios scatter around
   ``log(1 - δ) < 0``.  An effect may also test its signature directly on the validation
   data (``direct_test``: a clipped output piles up at its level,
   :func:`tendonkit.diagnose.stats.atom_test`); the finding's p-value is then the Bonferroni
   combination ``2·min(p_loss, p_direct)`` of the two routes.
6. **Naming.** The significant finding with the largest gain names the cause; with none the
   cause is ``none``.  Parsimony breaks ties: a significant finding with fewer added
   parameters, at least ``tie_ratio`` of the best gain, that the best one does not beat
   significantly names the cause instead.
   The margin to the best finding of another cause is reported; when that runner-up is
   significant too and about as good (gain within ``tie_ratio``, or not significantly
   worse), the result says so and names an experiment that would tell the two apart.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset
from ..errors import OptionError
from ..metrics import fit
from ..schema import Model
from ..simulate import _aligned, simulate
from .findings import (
    DEFAULT_EXPERIMENT,
    DISCRIMINATING,
    Diagnosis,
    Finding,
    _ambiguity,
    _mean,
)
from .residuals import ResidualAnalysis, analyse
from .stats import holm, loss_test

FloatArray = NDArray[np.float64]

# -- what effects receive -------------------------------------------------------------------------


@dataclass
class Context:
    """What an effect gets to build its extension: training data only, never validation data.

    Attributes
    ----------
    train : Dataset
        All training data.
    baseline : Model
        The baseline identified on ``train``.
    identifier : object
        The baseline's identifier options object (``identify(dataset) -> Model``).
    residuals : ResidualAnalysis
        The baseline analysed on ``train``.
    """

    train: Dataset
    baseline: Model
    identifier: Any
    residuals: ResidualAnalysis
    seed: int = 0
    _cache: dict[str, Any] = field(default_factory=dict)

    def refit(self, data: Dataset) -> Model:
        """Identify with the baseline's identifier and options on ``data`` (no training fit)."""
        from ..identification import without_training_fit

        with without_training_fit():
            return self.identifier.identify(data)

    def score(self, model: Model) -> float:
        """Mean free-run fit of ``model`` on the training data (-inf if it diverges)."""
        return mean_fit(model, self.train)

    @property
    def baseline_score(self) -> float:
        """:meth:`score` of the baseline (cached)."""
        if "baseline_score" not in self._cache:
            self._cache["baseline_score"] = self.score(self.baseline)
        return float(self._cache["baseline_score"])

    def best_extension(
        self,
        candidates: Iterable[tuple[dict[str, Any], Callable[[Dataset], Model]]],
        description: str,
    ) -> Extension | None:
        """The :class:`Extension` of the best candidate (:meth:`select`), or None."""
        params, model, score, _ = self.select(candidates)
        return self.extension(params, model, score, description)

    def extension(
        self, params: dict[str, Any], model: Model | None, score: float, description: str
    ) -> Extension | None:
        """The :class:`Extension` for a model chosen with :meth:`select` (None if there is none)."""
        if model is None:
            return None
        return Extension(
            model=model,
            params=params,
            description=description,
            train_gain=score - self.baseline_score,
        )

    def select(
        self, candidates: Iterable[tuple[dict[str, Any], Callable[[Dataset], Model]]]
    ) -> tuple[dict[str, Any], Model | None, float, list[dict[str, Any]]]:
        """Choose among ``(params, build)`` candidates by their training simulation fit.

        Returns the best parameters, the best model (built on ``train``), its score
        (:meth:`score`) and every candidate's score.
        """
        best: tuple[dict[str, Any], Model | None, float] = ({}, None, -math.inf)
        tried: list[dict[str, Any]] = []
        for params, build in candidates:
            try:
                model = build(self.train)
                score = self.score(model)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError) as exc:
                tried.append({"params": params, "score": None, "error": str(exc)})
                continue
            tried.append({"params": params, "score": score})
            if score > best[2]:
                best = (params, model, score)
        return best[0], best[1], best[2], tried


@dataclass(frozen=True)
class Extension:
    """An effect's proposal: the extended model (fitted on all training data) and its parameters."""

    model: Model
    params: dict[str, Any]
    description: str
    #: Gain of the training simulation fit (points).  It sets the effect's share of the error
    #: budget in the weighted Holm adjustment; 0 or less means the effect cannot name a cause.
    train_gain: float = 0.0

    @property
    def n_params(self) -> int:
        """Scalar parameters the extension added (terms × outputs, plus block parameters)."""
        return added_parameters(self.model)


# -- scoring --------------------------------------------------------------------------------------


def _simulate_all(model: Model, data: Dataset) -> FloatArray:
    data = _aligned(model, data)
    sims = [simulate(model, e.u, y=e.y, initial="estimate") for e in data.experiments]
    return np.vstack(sims)


def mean_fit(model: Model, data: Dataset) -> float:
    """Mean free-run fit over outputs (``-inf`` when the simulation diverges)."""
    data = _aligned(model, data)
    f = fit(data.y, _simulate_all(model, data))
    return float(np.mean(f)) if np.all(np.isfinite(f)) else -math.inf


def _loss(y: FloatArray, y_hat: FloatArray) -> FloatArray:
    var = np.var(y, axis=0)
    var[var == 0] = 1.0
    with np.errstate(over="ignore", invalid="ignore"):
        e = np.where(np.isfinite(y_hat), y - y_hat, 1e6)
        loss = np.sum(e**2 / var, axis=1)
    # A diverged simulation costs the same wherever it went: a cap keeps the batch statistics
    # of the test finite (normalised losses of a working model are of order 1).
    return np.where(np.isfinite(loss), np.minimum(loss, 1e12), 1e12)


# -- the procedure --------------------------------------------------------------------------------


def diagnose(
    train: Dataset,
    valid: Dataset,
    *,
    method: str = "arx",
    options: dict[str, Any] | None = None,
    effects: Sequence[str] | None = None,
    alpha: float = 0.01,
    min_relative_gain: float = 0.02,
    min_gain: float = 0.25,
    tie_ratio: float = 0.8,
    seed: int = 0,
    progress: bool = False,
    fallback: bool = True,
) -> Diagnosis:
    """Diagnose what the baseline model gets wrong on ``valid`` (see the module docstring).

    Parameters
    ----------
    train, valid : Dataset
        Training and validation data with the same inputs and outputs.
    method : str
        Registered identifier used for the baseline (and re-identification).
    options : dict, optional
        Options of the identifier.
    effects : sequence of str, optional
        Names of the effects to try (default: every registered effect).
    alpha : float
        Family-wise significance level over all effects tried (Holm–Bonferroni).
    min_relative_gain : float
        Margin δ of the test: a finding counts only if it removes more than this share of the
        baseline's validation error energy, ``H0: E[L_ext] >= (1 - δ) E[L_base]``.
    min_gain : float
        Smallest validation gain (points of mean fit) that can name a cause, however
        significant.  A good baseline leaves little error, and a small systematic improvement
        is then statistically certain without being an effect: on the robot's nominal plant a
        bilinear ARX fits 95.4 % and a one-sample lag gains +0.2–0.4 points with p < 1e-4
        (the robot suite uses 0.5 for that baseline).  The default 0.25 keeps weak effects on
        noisy data (a backlash at 5 % output noise gains +0.3).
    tie_ratio : float
        A runner-up whose gain reaches this fraction of the best gain is a tie.
    seed : int
        Seed for every random choice of the effects.
    progress : bool
        Show a progress bar.
    fallback : bool
        Check the baseline against a linear N4SID model of the training data
        (:func:`check_baseline`) and diagnose against N4SID when the baseline is grossly worse
        (an equation-error estimate biased by output noise): the gains of its extensions would
        measure that bias, not a cause.  ``False`` keeps the requested baseline (the check is
        still reported).

    Returns
    -------
    Diagnosis

    Examples
    --------
    >>> # doctest: +SKIP
    >>> d = diagnose(train, valid, method="arx")
    >>> d.cause, d.best.gain
    """
    from tqdm import tqdm

    from ..manager import effects as effect_registry
    from ..manager import identifiers

    problems = []
    if not 0 < alpha < 0.5:
        problems.append(f"alpha must be in (0, 0.5), found {alpha}.")
    if not 0 <= min_relative_gain < 1:
        problems.append(f"min_relative_gain must be in [0, 1), found {min_relative_gain}.")
    if not (isinstance(min_gain, int | float) and 0 <= min_gain < 100):
        problems.append(f"min_gain must be a number of points in [0, 100), found {min_gain!r}.")
    if not 0 < tie_ratio <= 1:
        problems.append(f"tie_ratio must be in (0, 1], found {tie_ratio}.")
    if (train.inputs, train.outputs) != (valid.inputs, valid.outputs):
        problems.append(
            f"training and validation data differ in signals: {train.inputs}->{train.outputs} "
            f"vs {valid.inputs}->{valid.outputs}."
        )
    if (options or {}).get("criterion") == "simulation":
        problems.append(
            "criterion 'simulation': diagnose re-estimates every extension by "
            "least squares, so the baseline must be estimated the same way (criterion "
            "'equation'); an output-error baseline would credit the extensions with the change "
            "of criterion instead of their cause."
        )
    registry = effect_registry()
    names = list(effects) if effects is not None else registry.names()
    unknown = [n for n in names if n not in registry.names()]
    if unknown:
        problems.append(f"unknown effects {unknown}; registered: {registry.names()}.")
    if problems:
        raise OptionError("diagnose cannot run:", problems)
    identifier = identifiers().get(method).create(**(options or {}))
    baseline = identifier.identify(train)
    check = check_baseline(baseline, train, method)
    if check is not None:
        check["fallback"] = bool(fallback and check["biased"])
        if check["fallback"]:
            method, identifier, baseline = "n4sid", check.pop("_identifier"), check.pop("_model")
        check.pop("_identifier", None)
        check.pop("_model", None)
    y_valid = _aligned(baseline, valid).y
    base_sim = _simulate_all(baseline, valid)
    base_fit = {n: float(v) for n, v in zip(baseline.output_names, fit(y_valid, base_sim))}
    base_loss = _loss(y_valid, base_sim)
    ctx = Context(
        train=train,
        baseline=baseline,
        identifier=identifier,
        residuals=analyse(baseline, train),
        seed=seed,
    )
    valid_res = analyse(baseline, valid)
    delta = float(min_relative_gain)
    raw: list[dict[str, Any]] = []
    losses: dict[str, FloatArray] = {}
    skipped: list[dict[str, str]] = []
    for name in tqdm(names, desc="diagnose", disable=not progress, unit="effect"):
        effect = registry.get(name)
        try:
            ext = effect.extend(ctx)
        except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError) as exc:
            skipped.append({"effect": name, "reason": f"{type(exc).__name__}: {exc}"})
            continue
        if ext is None:
            skipped.append({"effect": name, "reason": "not applicable to these data"})
            continue
        sim = _simulate_all(ext.model, valid)
        f = fit(y_valid, sim)
        ext_fit = {
            n: float(v) if np.isfinite(v) else -1e300 for n, v in zip(baseline.output_names, f)
        }
        loss = _loss(y_valid, sim)
        losses[name] = loss
        rel = float(1.0 - loss.mean() / base_loss.mean()) if base_loss.mean() > 0 else 0.0
        test = loss_test(base_loss, loss, margin=delta)
        test_info: dict[str, Any] = {**test.to_dict(), "margin": delta}
        p_value = test.p_value
        direct = _direct_test(effect, ctx, ext, valid)
        if direct is not None:
            # Two routes to the same finding: Bonferroni over them keeps its level.
            p_value = min(1.0, 2.0 * min(test.p_value, direct["p_value"]))
            test_info.update(loss_p_value=test.p_value, direct=direct)
        gain = _mean(ext_fit) - _mean(base_fit) if np.all(np.isfinite(f)) else -math.inf
        evidence = effect.signature(ctx, baseline, valid, valid_res) or {}
        raw.append(
            {
                "cause": effect.cause,
                "effect": name,
                "gain": float(gain),
                "fit": ext_fit,
                "relative_gain": rel,
                "p_value": p_value,
                "params": ext.params,
                "evidence": evidence,
                "description": ext.description,
                "model": ext.model,
                "n_params": ext.n_params - added_parameters(baseline),
                "test": {**test_info, "train_gain": ext.train_gain},
                "train_gain": ext.train_gain,
            }
        )
    # Weighted Holm: the weights come from the *training* gains (fixed before the validation
    # data are looked at), so the effects that found structure in the training data get most
    # of the error budget α, and an extension that did not improve the training fit cannot
    # name a cause.
    adjusted = holm(
        [r["p_value"] for r in raw], [max(r["train_gain"], 0.0) for r in raw] if raw else None
    )
    findings = [
        Finding(
            **{k: v for k, v in r.items() if k != "train_gain"},
            p_adjusted=p_adj,
            significant=bool(p_adj < alpha and r["gain"] > 0 and r["gain"] >= min_gain),
        )
        for r, p_adj in zip(raw, adjusted)
    ]
    findings.sort(key=lambda f: f.gain, reverse=True)
    best = _name_cause(findings, losses, alpha, tie_ratio)
    findings = [_with_training_fit(f, train) for f in findings]
    if best is not None:
        best = next(f for f in findings if f.effect == best.effect)
    ambiguous = _ambiguity(findings, best, losses, tie_ratio, alpha) if best else None
    return Diagnosis(
        cause=best.cause if best else "none",
        baseline_method=method,
        baseline=baseline,
        baseline_fit=base_fit,
        findings=tuple(findings),
        residuals=valid_res,
        ambiguous=ambiguous,
        settings={
            "alpha": alpha,
            "min_relative_gain": min_relative_gain,
            "min_gain": min_gain,
            "tie_ratio": tie_ratio,
            "seed": seed,
            "effects": names,
            "options": dict(options or {}),
            "test": "one-sided t-test over batches of log((1 - min_relative_gain) L_base / "
            "L_ext), batches of 4 autocorrelation times; Holm adjustment over the effects "
            "tried, weighted by their training gains",
        },
        skipped=tuple(skipped),
        named_effect=best.effect if best else None,
        baseline_check=check,
    )


def _direct_test(
    effect: Any, ctx: Context, ext: Extension, valid: Dataset
) -> dict[str, Any] | None:
    """An effect's direct test of its signature on the validation data, if it has one.

    Optional effect method ``direct_test(ctx, extension, valid) -> dict | None``; the dict
    holds a ``p_value`` under the hypothesis that the data do not show the effect where the
    extension puts it (a saturation: the output piled up at the clip level).
    """
    method = getattr(effect, "direct_test", None)
    if not callable(method):
        return None
    out = method(ctx, ext, valid)
    if out is None:
        return None
    try:
        p = float(out["p_value"])
    except (TypeError, KeyError, ValueError):
        p = math.nan
    if not 0.0 <= p <= 1.0:
        from ..errors import PluginError

        raise PluginError(
            f"effect {getattr(effect, 'name', effect)!r}:",
            [f"direct_test() must return None or a dict with a p_value in [0, 1], got {out!r}."],
        )
    return {**out, "p_value": p}


#: A baseline whose training free-run error energy exceeds this multiple of a linear N4SID
#: model's is treated as biased (:func:`check_baseline`).
BIAS_RATIO = 2.5


def check_baseline(baseline: Model, train: Dataset, method: str) -> dict[str, Any] | None:
    """Compare the baseline's free run on the training data with a linear N4SID model's.

    An equation-error estimate (ARX) is biased when the outputs carry measurement noise, badly
    so for slow sampling of lightly damped dynamics: its simulation can be far worse than the
    best linear model of the same data.  Any extension re-estimated by equation error then
    changes that bias, and a "gain" that only repairs it would be read as a cause (measured:
    a noisy linear oscillator at 100 samples per period gave ``coulomb_friction`` with ARX(8, 8)
    on 3 of 3 seeds).  N4SID is consistent under output noise.  With training error energies
    ``E_base`` and ``E_n4sid`` (the loss of :func:`diagnose`, averaged), the baseline is
    *biased* when ``E_base > BIAS_RATIO · E_n4sid``.  Returns None when the baseline is N4SID
    or the reference cannot be identified.
    """
    from ..errors import TendonkitError
    from ..manager import identifiers

    if method == "n4sid":
        return None
    try:
        ident = identifiers().get("n4sid").create()
        ref = ident.identify(train)
        y = _aligned(baseline, train).y
        e_base = float(np.mean(_loss(y, _simulate_all(baseline, train))))
        e_ref = float(np.mean(_loss(y, _simulate_all(ref, train))))
    except (TendonkitError, np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None
    ratio = e_base / e_ref if e_ref > 0 else math.inf
    return {
        "reference": "n4sid",
        "requested_method": method,
        "error_ratio": ratio,
        "threshold": BIAS_RATIO,
        "biased": bool(ratio > BIAS_RATIO),
        "reference_fit": mean_fit(ref, train),
        "_identifier": ident,
        "_model": ref,
    }


def added_parameters(model: Model) -> int:
    """Count the parameters of a model's blocks and nonlinear terms.

    A term has one coefficient per output (per state for state space).  Blocks are counted
    per kind and parameter, not per signal: the effects derive every signal's block from one
    chosen value (a delay, a width as a fraction of each signal's spread), so four play blocks
    on four inputs add one free parameter, like two on two outputs.
    """
    rep = model.representation
    n_terms = len(getattr(rep, "terms", ()))
    per_term = len(model.outputs) if not hasattr(rep, "E") else rep.n_states  # type: ignore[union-attr]
    kinds = {
        (where, b.kind, key)
        for where, blocks in (("in", model.input_blocks), ("out", model.output_blocks))
        for b in blocks
        for key in b.params
    }
    return n_terms * per_term + len(kinds)


def _name_cause(
    findings: list[Finding], losses: dict[str, FloatArray], alpha: float, tie_ratio: float
) -> Finding | None:
    """The significant finding with the largest gain, unless a simpler one is as good.

    Parsimony breaks ties: a significant finding with fewer added parameters, a gain of at
    least ``tie_ratio`` of the best one's, and that the best one does not beat significantly
    (same one-sided test, no margin) names the cause instead: an extension that contains
    another must earn its extra parameters.  (Without the gain condition a simpler finding
    with a tenth of the gain could win whenever the batch test is inconclusive.)
    """
    sig = [f for f in findings if f.significant]
    if not sig:
        return None
    best = sig[0]
    for f in sig[1:]:
        if f.n_params >= best.n_params or f.gain < tie_ratio * best.gain:
            continue
        if loss_test(losses[f.effect], losses[best.effect]).p_value >= alpha:
            return f
    return best


def _with_training_fit(f: Finding, train: Dataset) -> Finding:
    """Fill in the training fit of a finding's extended model (skipped while searching)."""
    from ..identification import training_fit

    if f.model is None or not f.significant:
        return f
    prov = dataclasses.replace(f.model.provenance, training_fit=training_fit(f.model, train))
    return dataclasses.replace(f, model=f.model.replace(provenance=prov))


def params_of(model: Model) -> dict[str, Any]:
    """The blocks and terms a diagnosis added to a model, for display."""
    rep = model.representation
    terms = [t.label for t in getattr(rep, "terms", ())]
    return {
        "input_blocks": [dataclasses.asdict(b) for b in model.input_blocks],
        "output_blocks": [dataclasses.asdict(b) for b in model.output_blocks],
        "terms": terms,
    }


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
