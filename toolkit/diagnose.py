"""Diagnose: show what a model's simulation gets wrong, name the cause, extend, measure the gain.

The procedure, for any registered identifier as the baseline and any registered effects:

1. **Baseline.** Identify on the training data; simulate (free run) on the validation data.
2. **Residuals.** Analyse where the validation error concentrates and how the one-step
   residuals correlate with the inputs (:mod:`tendonkit.residuals`).
3. **Candidates.** Every effect proposes an extension of the baseline with its own parameters
   (a delay, a dead-zone threshold, a friction term, ...).  Each candidate is fitted on the
   *training* data and its parameters are chosen by its free-run simulation fit on the same
   training data.  (An inner train/check split was tried first and rejected: an effect that
   shows only in part of a record — the tanks overflow early in theirs — is then invisible to
   the selection.  An effect adds one or two parameters, so the in-sample simulation fit is a
   sound criterion; the honest test is the next step.)
4. **Gain.** Each extended model is simulated on the validation data, which no choice above has
   seen.  The gain is the change in mean fit (percentage points).
5. **Significance.** A gain counts only if it is both *statistically* significant — a one-sided
   batch-means t-test on the per-sample loss difference (squared errors normalised by output
   variance), robust to the strong autocorrelation of simulation errors — and *practically*
   significant: the validation error energy must drop by at least ``min_relative_gain``.
   Noise alone then never names a cause: without structure the loss difference has zero mean.
6. **Naming.** The significant finding with the largest gain names the cause; with none the
   cause is ``none``.  Parsimony breaks statistical ties: when a finding with fewer added
   parameters is not significantly worse on the validation loss than the best one, it names
   the cause instead (an extension that contains another must earn its extra parameters).  When the runner-up explains the data about as well (its gain is within
   ``tie_ratio`` of the best, or the two extended models are not significantly different),
   the result says so and names an experiment that would tell the two apart.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset
from tendonkit.errors import OptionError
from tendonkit.metrics import fit
from tendonkit.residuals import ResidualAnalysis, analyse
from tendonkit.schema import Model
from tendonkit.simulate import _aligned, simulate

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
        from tendonkit.identification import without_training_fit

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

    def select(
        self, candidates: Iterable[tuple[dict[str, Any], Callable[[Dataset], Model]]]
    ) -> tuple[dict[str, Any], Model | None, float, list[dict[str, Any]]]:
        """Choose among ``(params, build)`` candidates by their training simulation fit.

        Returns the best parameters, the best model (built on ``train``), its score and every
        candidate's score.
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
    train_gain: float = 0.0  # gain of the training simulation fit, for information

    @property
    def n_params(self) -> int:
        """Scalar parameters the extension added (terms × outputs, plus block parameters)."""
        return added_parameters(self.model)


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

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (without the model)."""
        return {
            "n_params": self.n_params,
            "cause": self.cause,
            "effect": self.effect,
            "gain": self.gain,
            "fit": self.fit,
            "relative_gain": self.relative_gain,
            "p_value": self.p_value,
            "significant": self.significant,
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

    @property
    def best(self) -> Finding | None:
        """The finding that names the cause (None when the cause is ``none``)."""
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
            },
            "extended": {
                "fit": _mean(self.extended_fit),
                "fit_per_output": self.extended_fit,
                "gain": best.gain if best else 0.0,
                "effect": best.effect if best else None,
                "params": best.params if best else {},
                "model": model_path,
            },
            "margin_to_runner_up": self.margin,
            "ambiguous": self.ambiguous,
            "findings": [f.to_dict() for f in self.findings],
            "skipped": list(self.skipped),
            "residuals": self.residuals.to_dict(),
            "settings": self.settings,
        }

    @property
    def margin(self) -> float | None:
        """Gain of the best finding minus the runner-up's (percentage points)."""
        if len(self.findings) < 2 or self.best is None:
            return None
        return self.findings[0].gain - self.findings[1].gain


def _mean(d: dict[str, float]) -> float:
    return float(np.mean(list(d.values()))) if d else float("nan")


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


def batch_means_test(d: FloatArray, n_batches: int = 10) -> float:
    """One-sided p-value that the mean of ``d`` is > 0, from contiguous batch means.

    Batch means stay valid when ``d`` is strongly autocorrelated (simulation errors are), as
    long as the batches are much longer than the correlation time.
    """
    from scipy import stats

    d = np.asarray(d, dtype=float)
    if not np.all(np.isfinite(d)):
        return 1.0
    n = len(d)
    b = max(min(n_batches, n // 20), 2)
    means = np.array([chunk.mean() for chunk in np.array_split(d, b)])
    sd = means.std(ddof=1)
    if sd == 0:
        return 0.0 if means.mean() > 0 else 1.0
    t = means.mean() / (sd / np.sqrt(b))
    return float(stats.t.sf(t, df=b - 1))


def _loss(y: FloatArray, y_hat: FloatArray) -> FloatArray:
    var = np.var(y, axis=0)
    var[var == 0] = 1.0
    e = np.where(np.isfinite(y_hat), y - y_hat, 1e6)
    return np.sum(e**2 / var, axis=1)


# -- the procedure --------------------------------------------------------------------------------


def diagnose(
    train: Dataset,
    valid: Dataset,
    *,
    method: str = "arx",
    options: dict[str, Any] | None = None,
    effects: Sequence[str] | None = None,
    alpha: float = 0.01,
    min_relative_gain: float = 0.05,
    tie_ratio: float = 0.8,
    seed: int = 0,
    progress: bool = False,
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
        Significance level of the one-sided test on the validation loss difference.
    min_relative_gain : float
        Smallest relative drop of the validation error energy that counts.
    tie_ratio : float
        A runner-up whose gain reaches this fraction of the best gain is a tie.
    seed : int
        Seed for every random choice of the effects.
    progress : bool
        Show a progress bar.

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

    from tendonkit.manager import effects as effect_registry
    from tendonkit.manager import identifiers

    problems = []
    if not 0 < alpha < 0.5:
        problems.append(f"alpha must be in (0, 0.5), found {alpha}.")
    if not 0 <= min_relative_gain < 1:
        problems.append(f"min_relative_gain must be in [0, 1), found {min_relative_gain}.")
    if (train.inputs, train.outputs) != (valid.inputs, valid.outputs):
        problems.append(
            f"training and validation data differ in signals: {train.inputs}->{train.outputs} "
            f"vs {valid.inputs}->{valid.outputs}."
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
    y_valid = valid.y
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
    findings: list[Finding] = []
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
        rel = float(1.0 - loss.mean() / base_loss.mean()) if base_loss.mean() > 0 else 0.0
        p = batch_means_test(base_loss - loss)
        gain = _mean(ext_fit) - _mean(base_fit) if np.all(np.isfinite(f)) else -math.inf
        significant = bool(p < alpha and rel >= min_relative_gain and gain > 0)
        evidence = effect.signature(ctx, baseline, valid, valid_res) or {}
        findings.append(
            Finding(
                cause=effect.cause,
                effect=name,
                gain=float(gain),
                fit=ext_fit,
                relative_gain=rel,
                p_value=p,
                significant=significant,
                params=ext.params,
                evidence=evidence,
                description=ext.description,
                model=ext.model,
                n_params=ext.n_params - added_parameters(baseline),
            )
        )
    findings.sort(key=lambda f: (f.significant, f.gain), reverse=True)
    findings = _parsimony(findings, valid, alpha)
    findings = [_with_training_fit(f, train) for f in findings]
    best = next((f for f in findings if f.significant), None)
    ambiguous = _ambiguity(findings, valid, tie_ratio, alpha) if best else None
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
            "tie_ratio": tie_ratio,
            "seed": seed,
            "effects": names,
            "options": dict(options or {}),
        },
        skipped=tuple(skipped),
    )


def added_parameters(model: Model) -> int:
    """Count the scalar parameters in a model's blocks and nonlinear terms."""
    rep = model.representation
    n_terms = len(getattr(rep, "terms", ()))
    per_term = len(model.outputs) if not hasattr(rep, "E") else rep.n_states  # type: ignore[union-attr]
    blocks = sum(len(b.params) for b in (*model.input_blocks, *model.output_blocks))
    return n_terms * per_term + blocks


def _parsimony(findings: list[Finding], valid: Dataset, alpha: float) -> list[Finding]:
    """Move a simpler significant finding that is not significantly worse to the front."""
    sig = [f for f in findings if f.significant]
    if len(sig) < 2 or sig[0].model is None:
        return findings
    best = sig[0]
    y = valid.y
    l_best = _loss(y, _simulate_all(best.model, valid))
    for f in sig[1:]:
        if f.n_params >= best.n_params or f.model is None:
            continue
        l_f = _loss(y, _simulate_all(f.model, valid))
        if batch_means_test(l_f - l_best) >= alpha:  # best is not significantly better
            rest = [g for g in findings if g is not f]
            return [f, *rest]
    return findings


def _with_training_fit(f: Finding, train: Dataset) -> Finding:
    """Fill in the training fit of a finding's extended model (skipped while searching)."""
    from tendonkit.identification import training_fit

    if f.model is None or not f.significant:
        return f
    prov = dataclasses.replace(f.model.provenance, training_fit=training_fit(f.model, train))
    return dataclasses.replace(f, model=f.model.replace(provenance=prov))


def _ambiguity(
    findings: list[Finding], valid: Dataset, tie_ratio: float, alpha: float
) -> dict[str, Any] | None:
    sig = [f for f in findings if f.significant]
    if len(sig) < 2:
        return None
    a, b = sig[0], sig[1]
    if a.cause == b.cause:
        return None
    close = b.gain >= tie_ratio * a.gain
    if not close and a.model is not None and b.model is not None:
        y = valid.y
        la = _loss(y, _simulate_all(a.model, valid))
        lb = _loss(y, _simulate_all(b.model, valid))
        close = batch_means_test(lb - la) >= alpha
    if not close:
        return None
    return {
        "between": [a.cause, b.cause],
        "gains": [a.gain, b.gain],
        "statement": (
            f"{a.cause} (gain {a.gain:.2f}) and {b.cause} (gain {b.gain:.2f}) explain these data "
            "about equally well."
        ),
        "experiment": DISCRIMINATING.get(frozenset({a.cause, b.cause}), DEFAULT_EXPERIMENT),
    }


def params_of(model: Model) -> dict[str, Any]:
    """The blocks and terms a diagnosis added to a model, for display."""
    rep = model.representation
    terms = [t.label for t in getattr(rep, "terms", ())]
    return {
        "input_blocks": [dataclasses.asdict(b) for b in model.input_blocks],
        "output_blocks": [dataclasses.asdict(b) for b in model.output_blocks],
        "terms": terms,
    }
