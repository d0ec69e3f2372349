"""Automatic ARX structure: delays per input (MATLAB's ``delayest``), then orders.

1. **Delays** (``nk="auto"``), per input: ARX(2, 2) models with that input's delay set to
   0, 1, …, ``max_delay`` (the other inputs at delay 1) are fitted by least squares; the delay
   with the smallest one-step prediction loss wins, the smaller delay on a tie within 0.1 %
   (``delayest``'s procedure; its default orders are 2 and 2).  ``delayest`` proposes, the
   cross-validation of step 2 decides: where it finds a dead time (a delay beyond one
   sample), the orders are scored both with it and without it (every input at
   ``min(delay, 1)``), and a dead time counts as one parameter in the tie rule.  On a lightly
   damped plant with several outputs an ARX(2, 2) leaves most of the one-step error to its
   too-short autoregression, the delay hardly changes that loss, and its minimum can fall
   anywhere: a three-mass chain at 5 ms with no dead time gave 59 samples, and a model
   with that delay simulates its validation data worse than their mean.
2. **Orders** (``na``/``nb="auto"``): every ``na`` in 0 … ``max_order`` and ``nb`` in
   1 … ``max_order`` (one ``nb`` for all inputs) is scored by the same blocked
   cross-validation as :mod:`tendonkit.plugins.pem`: every experiment cut into four blocks,
   each held out in turn, the model fitted on the rest and simulated on the held-out block
   from the measured history of its first samples; the lowest held-out simulation error
   wins, the model with fewer parameters on a tie within 1 %.  MATLAB's ``arxstruc`` and
   ``selstruc`` score the one-step prediction loss instead; a simulation score is what the
   model is used for, and the one-step loss keeps falling with the order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from tendonkit.dataset import Dataset, Experiment
from tendonkit.errors import OptionError, TendonkitError
from tendonkit.identification import without_training_fit
from tendonkit.parallel import map_tasks
from tendonkit.predict import predict
from tendonkit.simulate import simulate

#: Blocks of the cross-validation, and the relative margin within which fewer parameters win.
FOLDS = 4
PARSIMONY = 0.01


def select(
    options: Any, data: Dataset
) -> tuple[int, tuple[int, ...], tuple[int, ...], bool, dict[str, Any]]:
    """Concrete ``(na, nb, nk, offset)`` for the ``"auto"`` entries of ``options``, and the record."""
    nu = data.nu
    record: dict[str, Any] = {}
    if options.nk == "auto":
        nk, losses = estimate_delays(options, data)
        record["delays"] = losses
    else:
        nk = as_tuple(options.nk, nu)
    # a dead time found by delayest is a proposal: the orders are scored without it too
    undelayed = tuple(min(k, 1) for k in nk)
    delays = [nk, undelayed] if options.nk == "auto" and undelayed != nk else [nk]
    na_fixed = None if options.na == "auto" else int(options.na)
    nb_fixed = None if options.nb == "auto" else as_tuple(options.nb, nu)
    offsets = [False, True] if options.offset == "auto" else [bool(options.offset)]
    if na_fixed is not None and nb_fixed is not None and len(offsets) == 1 and len(delays) == 1:
        return na_fixed, nb_fixed, nk, offsets[0], record
    nas = range(0, options.max_order + 1) if na_fixed is None else [na_fixed]
    nbs: list[tuple[int, ...]] = (
        [(b,) * nu for b in range(1, options.max_order + 1)] if nb_fixed is None else [nb_fixed]
    )
    pairs = [(na, nb) for na in nas for nb in nbs]
    if options.equal_orders and na_fixed is None and nb_fixed is None:
        pairs = [(n, (n,) * nu) for n in range(1, options.max_order + 1)]
    window = cv_window(options.max_order, nk)
    folds = cv_folds(data, window)
    candidates = [(offset, na, nb, d) for d in delays for offset in offsets for na, nb in pairs]
    # the candidates are independent: options.jobs workers score them (tendonkit.parallel)
    errors = map_tasks(
        _score, candidates, shared=(options, folds, window), jobs=getattr(options, "jobs", 1)
    )
    rows = []
    for (offset, na, nb, d), err in zip(candidates, errors, strict=True):
        if err is not None:
            n_par = na * data.ny + sum(nb) + int(offset) + sum(k > 1 for k in d)
            row = {"na": na, "nb": list(nb), "offset": offset}
            if len(delays) > 1:
                row["nk"] = list(d)
            rows.append({**row, "parameters": n_par, "held_out_rms": err})
    if not rows:
        raise OptionError("arx: no order could be fitted on the cross-validation folds.")
    top = min(r["held_out_rms"] for r in rows)
    eligible = [r for r in rows if r["held_out_rms"] <= top * (1.0 + PARSIMONY)]
    best = min(eligible, key=lambda r: (r["parameters"], r["held_out_rms"]))
    for r in rows:
        r["selected"] = r is best
    record["candidates"] = rows
    chosen = tuple(best.get("nk", nk))
    return int(best["na"]), tuple(best["nb"]), chosen, bool(best["offset"]), record


def _score(
    shared: tuple[Any, ...], candidate: tuple[bool, int, tuple[int, ...], tuple[int, ...]]
) -> float | None:
    """Held-out simulation error of one ``(offset, na, nb, nk)`` (None: it cannot be fitted)."""
    options, folds, window = shared
    offset, na, nb, nk = candidate
    trial = dataclasses.replace(
        options, na=na, nb=nb, nk=nk, offset=offset, criterion="equation", jobs=1
    )
    try:
        return _held_out(trial, folds, window)
    except TendonkitError:
        return None


def as_tuple(v: Any, n: int) -> tuple[int, ...]:
    """One value for each of ``n`` inputs (a tuple or list as given)."""
    return tuple(v) if isinstance(v, tuple | list) else (int(v),) * n


#: ``max_delay="auto"``: a twentieth of the shortest experiment, within these bounds.
AUTO_DELAY_MIN, AUTO_DELAY_MAX = 10, 160


def delay_range(options: Any, data: Dataset) -> int:
    """Largest delay ``delayest`` tries: ``options.max_delay``, or for ``"auto"`` as far as the
    data support — a twentieth of the shortest experiment (a dead time of 30 samples on 2,000
    was out of reach of a fixed 10: the model fitted 1.6 %), at least 10 and at most 160."""
    if options.max_delay != "auto":
        return int(options.max_delay)
    shortest = min(e.n_samples for e in data.experiments)
    return int(min(AUTO_DELAY_MAX, max(AUTO_DELAY_MIN, shortest // 20)))


def estimate_delays(options: Any, data: Dataset) -> tuple[tuple[int, ...], list[dict[str, Any]]]:
    """Each input's delay by ``delayest``'s procedure (module notes), and the losses.

    ``options`` is an ARX options object (its ``max_delay``, :func:`delay_range`, and its
    ``ridge`` are used).
    """
    nu = data.nu
    nk = [1] * nu
    record = []
    max_delay = delay_range(options, data)
    for m in range(nu):
        losses = []
        for d in range(max_delay + 1):
            trial_nk = list(nk)
            trial_nk[m] = d
            trial = dataclasses.replace(
                options, na=2, nb=2, nk=tuple(trial_nk), criterion="equation", offset=True
            )
            try:
                with without_training_fit():
                    model = trial.identify(data)
            except TendonkitError:
                losses.append(np.inf)
                continue
            losses.append(_one_step_loss(model, data, 2 + max_delay + 1))
        best = min(losses)
        nk[m] = next(d for d, v in enumerate(losses) if v <= best * (1.0 + 1e-3))
        record.append({"input": data.inputs[m], "loss_by_delay": losses, "delay": nk[m]})
    return tuple(nk), record


def _one_step_loss(model: Any, data: Dataset, lag: int) -> float:
    err = [(e.y[lag:] - predict(model, e.u, e.y, 1)[lag:]).ravel() for e in data.experiments]
    e = np.concatenate(err)
    return float(np.mean(e**2)) if np.all(np.isfinite(e)) else np.inf


def cv_window(max_order: int, nk: tuple[int, ...]) -> int:
    """Initialisation window of the held-out blocks: at least 10 samples, and the history of
    the largest candidate (``max_order`` lags after the longest delay)."""
    return max(10, max_order + max(nk) + 1)


def cv_folds(data: Dataset, window: int) -> list[tuple[Dataset, list[Experiment]]]:
    """:meth:`Dataset.blocked_folds` with pieces long enough for the window's history."""
    out = [
        (f, list(h.experiments)) for f, h in data.blocked_folds(FOLDS, 2 * window + 1, window + 1)
    ]
    if not out:
        raise OptionError(
            "arx: the experiments are too short for the cross-validation that chooses the "
            "structure; give every structure option that is 'auto' (na, nb, nk and offset)."
        )
    return out


def _held_out(options: Any, folds: list[tuple[Dataset, list[Experiment]]], window: int) -> float:
    def build(data: Dataset) -> Any:
        with without_training_fit():
            return options.identify(data)

    return held_out_error(build, folds, window)


def held_out_or_inf(
    build: Callable[[Dataset], Any], folds: list[tuple[Dataset, list[Experiment]]], window: int
) -> float:
    """:func:`held_out_error`, infinite where ``build`` cannot be fitted or simulated on a
    fold (a candidate structure that fails loses instead of stopping its caller)."""
    try:
        return held_out_error(build, folds, window)
    except (TendonkitError, ValueError, np.linalg.LinAlgError):
        return float("inf")


def held_out_error(
    build: Callable[[Dataset], Any], folds: list[tuple[Dataset, list[Experiment]]], window: int
) -> float:
    """Normalised RMS simulation error of ``build(fit part)`` on the held-out blocks of
    :func:`cv_folds`, each started from its first ``window`` samples and scored after them."""
    sq, count = 0.0, 0
    sy = None
    for fit_data, held in folds:
        model = build(fit_data)
        if sy is None:
            sy = np.std(np.vstack([e.y for e in fit_data.experiments]), axis=0)
            sy[~(sy > 0)] = 1.0
        with np.errstate(all="ignore"):
            for e in held:
                sim = simulate(model, e.u, y=e.y, initial="estimate", init_window=window)
                err = (e.y[window:] - sim[window:]) / sy
                sq += float(np.sum(err**2))
                count += err.size
    return float(np.sqrt(sq / count)) if np.isfinite(sq) else float("inf")
