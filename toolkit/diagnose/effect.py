"""The effect-plugin contract of ``diagnose``, in one place.

An **effect** is a physical cause that ``diagnose`` can name (its ``cause`` is a word of the fixed
vocabulary :data:`tendonkit.registry.CAUSES`).  It is any object that satisfies the
:class:`Effect` protocol — no base class to inherit — registered from a plugin's
``tendonkit_register_effects(registry)`` hook with ``registry.add(effect)``
(:mod:`tendonkit.hookspecs`).  ``diagnose`` gives it a :class:`Context` (training data only) and
receives an :class:`Extension` (the baseline extended with the effect's structure).  An effect
that can also see its signature directly in the validation data implements the optional
:class:`DirectTest` protocol.  docs/diagnose.md, "Writing an effect", has a complete example.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset
from ..identification import without_training_fit
from ..metrics import fit
from ..schema import Model
from ..simulate import aligned, simulate
from ..terms import Term
from .extend import extend_with_terms
from .findings import reshape_reason, reshapes
from .residuals import ResidualAnalysis

__all__ = [
    "Context",
    "DirectTest",
    "Effect",
    "Extension",
    "added_parameters",
    "mean_fit",
    "simulate_all",
]

FloatArray = NDArray[np.float64]


@runtime_checkable
class Effect(Protocol):
    """What an effect plugin provides.

    Attributes
    ----------
    name : str
        Unique registry name (lowercase, e.g. ``"coulomb_friction"``).
    cause : str
        The cause it names, one of :data:`tendonkit.registry.CAUSES` (not ``"none"``).
    description : str
        One line for ``tendonkit plugins`` and the report (optional; empty if absent).

    Methods
    -------
    extend(ctx) -> Extension | None
        The baseline extended with the effect's structure, its parameters estimated on
        ``ctx.train`` only (:meth:`Context.select` chooses among candidates by their training
        fit).  None when the effect does not apply (e.g. no input to delay).
    signature(ctx, baseline, valid, residuals) -> dict
        Evidence of the effect in the validation residuals of the baseline (plain JSON data:
        ``statistic``, ``value`` and what the signal is); shown in the report, never used to
        decide.

    An effect may also implement :class:`DirectTest` (``direct_test``).
    """

    name: str
    cause: str

    def extend(self, ctx: Context) -> Extension | None:
        """The baseline extended with this effect's structure, fitted on training data."""
        ...

    def signature(
        self, ctx: Context, baseline: Model, valid: Dataset, res: ResidualAnalysis
    ) -> dict[str, Any]:
        """Evidence of the effect in the baseline's validation residuals (for the report)."""
        ...


@runtime_checkable
class DirectTest(Protocol):
    """Optional part of an :class:`Effect`: test its signature directly on validation data.

    ``direct_test(ctx, extension, valid)`` returns None (no test here) or a dict with a
    ``p_value`` in [0, 1] under the hypothesis that the data do not show the effect where the
    extension puts it (e.g. a clipped output piling up at its level).  ``diagnose`` then accepts
    the finding on either route, Bonferroni-corrected (docs/diagnose.md, *Direct evidence*).
    """

    def direct_test(
        self, ctx: Context, extension: Extension, valid: Dataset
    ) -> dict[str, Any] | None:
        """A p-value for the effect's signature on the validation data, or None."""
        ...


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
    #: Largest ARX order of a structure the effects may choose themselves (0: they keep the
    #: baseline's).  Set when the baseline chose its own orders on the training data (the
    #: automatic ARX): an effect that changes what the linear part sees (a curve after the
    #: dynamics) may choose the orders again with itself in place, the same way.
    max_order: int = 0
    #: The causes a diagnosis's sequence named before this step, as ``(cause, params, step)``:
    #: :meth:`select` leaves out a candidate of the effect being tried (:attr:`trying`, its
    #: cause) that only reshapes one of them (:func:`tendonkit.diagnose.findings.reshapes`).
    named: tuple[tuple[str, dict[str, Any], int], ...] = ()
    #: The cause of the effect being tried (set by diagnose around ``Effect.extend``).
    trying: str = ""
    _cache: dict[str, Any] = field(default_factory=dict)

    def refit(self, data: Dataset) -> Model:
        """Identify with the baseline's identifier and options on ``data`` (no training fit)."""

        with without_training_fit():
            return self.identifier.identify(data)

    def with_terms(self, terms: Sequence[Term]) -> Callable[[Dataset], Model]:
        """A candidate's builder: the baseline refitted on the data with the extra ``terms``
        (:func:`~tendonkit.diagnose.extend.extend_with_terms`, the baseline's identifier)."""
        return lambda d: extend_with_terms(self.baseline, d, terms, refit=self.refit)

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
            build=self.builder_of(model),
        )

    def builder_of(self, model: Model) -> Callable[[Dataset], Model] | None:
        """The ``build`` that :meth:`select` made ``model`` with (None if it did not)."""
        entry = self._cache.get("builders", {}).get(id(model))
        return entry[1] if entry is not None and entry[0] is model else None

    def reshaped(self, cause: str, params: dict[str, Any]) -> str:
        """Why an extension of ``cause`` with ``params`` only reshapes a cause named before
        (:attr:`named`; empty: it does not)."""
        for named, named_params, index in self.named:
            if reshapes(cause, params, named, named_params):
                return reshape_reason(cause, named, index)
        return ""

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
            reshaped = self.reshaped(self.trying, params) if self.trying else ""
            if reshaped:
                tried.append({"params": params, "score": None, "excluded": reshaped})
                self._cache.setdefault("reshaped", {})[self.trying] = reshaped
                continue
            try:
                model = build(self.train)
                score = self.score(model)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError) as exc:
                tried.append({"params": params, "score": None, "error": str(exc)})
                continue
            tried.append({"params": params, "score": score})
            if score > best[2]:
                best = (params, model, score)
                # Remembered so that a named extension can be refitted as the next step's
                # baseline (diagnose's sequence of causes): the model and its builder together.
                self._cache.setdefault("builders", {})[id(model)] = (model, build)
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
    #: ``build(data) -> Model``: the same structure fitted on other data.  When the extension
    #: names a cause, it is the refit of the next step of the sequence (its effects extend this
    #: model).  Set by :meth:`Context.extension` for models chosen with :meth:`Context.select`;
    #: without it the sequence stops after this cause.
    build: Callable[[Dataset], Model] | None = None
    #: The extended structure without the effect itself, where it is not the baseline: a
    #: *linear* model of more freedom than the baseline that the extension is built on (a
    #: curve between two filters has the filters, and the baseline's structure identified
    #: again behind them).  The extension must then beat it too on every route of the
    #: validation test (an intersection–union test: each route's p-value is the larger of the
    #: two), so that the gain of the added linear freedom is not read as the effect.
    linear_part: Model | None = None

    @property
    def n_params(self) -> int:
        """Scalar parameters the extension added (terms × outputs, plus block parameters)."""
        return added_parameters(self.model)


# -- scoring --------------------------------------------------------------------------------------


def simulate_all(model: Model, data: Dataset) -> FloatArray:
    """Free-run simulation of every experiment of ``data`` (initial state estimated), stacked."""
    data = aligned(model, data)
    sims = [simulate(model, e.u, y=e.y, initial="estimate") for e in data.experiments]
    return np.vstack(sims)


def mean_fit(model: Model, data: Dataset) -> float:
    """Mean free-run fit over outputs (``-inf`` when the simulation diverges)."""
    data = aligned(model, data)
    f = fit(data.y, simulate_all(model, data))
    return float(np.mean(f)) if np.all(np.isfinite(f)) else -math.inf


def added_parameters(model: Model) -> int:
    """Count the parameters of a model's blocks and nonlinear terms.

    A term has one coefficient per output (per state for state space).  Blocks are counted
    per kind and parameter, not per signal: the effects derive every signal's block from one
    chosen value (a delay, a width as a fraction of each signal's spread), so four play blocks
    on four inputs add one free parameter, like two on two outputs.  Filters
    (``second_order_section``) are estimated each on its own: every one counts.
    """
    rep = model.representation
    n_terms = len(getattr(rep, "terms", ()))
    per_term = len(model.outputs) if not hasattr(rep, "E") else rep.n_states  # type: ignore[union-attr]
    blocks = (*model.input_blocks, *model.output_blocks)
    sections = [b for b in blocks if b.kind == "second_order_section"]
    kinds = {
        (where, b.kind, key)
        for where, chain in (("in", model.input_blocks), ("out", model.output_blocks))
        for b in chain
        if b.kind != "second_order_section"
        for key in b.params
    }
    return n_terms * per_term + len(kinds) + sum(len(b.params) for b in sections)
