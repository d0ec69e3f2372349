"""PEM: prediction-error (output-error) identification of a linear state-space model.

MATLAB's ``ssest``/``pem`` with a zero noise model (the default ``focus``): every parameter of
a state-space model — ``A``, ``B``, ``C``, ``D`` where asked, the initial state of every
experiment, and the operating point (``y0``; ``u0`` for integrating plants) — is fitted by
minimising the free-run *simulation* error, the criterion the model is judged by.  The subspace step
(:mod:`tendonkit.plugins.n4sid`) gives the start.

Algorithm:

1. **Start.**  ``n4sid`` of the requested order on the mean-removed data.  With an
   ``integrator`` the subspace model is identified from the *differenced* outputs (a
   velocity model, with feedthrough) and completed by one pure integrator per output,
   ``q[k+1] = q[k] + v[k]``; the input offset ``u0`` starts where the mean velocity is zero.
2. **Delays and feedthrough** (``delay``/``feedthrough`` ``None``): each input's delay by
   ``delayest``'s procedure (:func:`tendonkit.plugins._arx_structure.estimate_delays`); an
   input without delay gets feedthrough, a delay of more than one sample becomes an input
   ``delay`` block of the model and the state space is identified on the delayed inputs.
3. **Refinement.**  The model is written in modal coordinates (:mod:`._modal`): one
   first-order recursion per real pole, per complex pair and per integrator.  Stability is a
   bound on the poles (``|p| <= 1 - 1e-6``; integrators stay at exactly 1), and the Jacobian
   is exact and costs a few compiled filters per mode.  :func:`scipy.optimize.least_squares`
   (trust-region reflective, Jacobian-scaled) minimises the output-normalised errors.
4. **Structure selection** (``order=None`` and/or ``integrator=None``) by **blocked
   cross-validation on the training data only**.  Every experiment is cut into ``folds``
   blocks (4); each block in turn is held out, the candidate is identified on the rest (the
   pieces before and after it as separate experiments) and simulated on the held-out block
   from the initial state estimated on its first ``init_window`` (10) samples, as the
   benchmarks score.  Why not an information criterion (AIC, BIC): those are computed from
   the estimation residuals and assume the model class holds, which on real data it does
   not; they never see what goes wrong in use — a slow mode that drifts over a long free
   run, or states that a short window cannot fix (the EMPS position: orders above two fit
   the training data better and drift off on held-out blocks by orders of magnitude).
   Integrating candidates are tried only when the best stable one has a mode that does not
   decay to 1/e over the shortest record (such a pole cannot be told from an integrator by
   these data).  The candidate with the lowest held-out error wins (the cross-validation itself charges a
   model for parameters that do not predict held-out data); a smaller one within 0.1 % of
   it — below what the candidates' refinement tolerance resolves — is preferred.  A family (with or without integrators) stops growing after two consecutive
   orders more than ten times worse than its best.  The winner is identified again on the
   whole record.  The candidates' table is stored in the provenance
   (``details["candidates"]``) and drawn by
   :func:`tendonkit.figures.plot_structure_selection` (``compare --plot``).
5. **Prediction focus** (``focus="prediction"``): the innovation form, the Kalman gain ``K``
   with every other parameter, refitted by the ``horizon``-step prediction error from the
   simulation-error model (:mod:`tendonkit.plugins._innovation`).
6. **Uncertainty.**  The Gauss–Newton covariance of the parameters at the optimum, mapped
   to the entries of the stored matrices, is kept in ``details["covariance"]``
   (:mod:`tendonkit.uncertainty` turns it into a confidence band on simulated outputs).

The result is a :class:`~tendonkit.schema.StateSpace` in real block-diagonal (modal) form
with its operating point ``u0``/``y0``; with the default focus no Kalman gain (an output-error
model has no noise model: prediction uses the gain fitted by :func:`tendonkit.predict.predict`),
with ``focus="prediction"`` the fitted ``K``.

References
----------
L. Ljung, *System Identification: Theory for the User*, 2nd ed., Prentice Hall, 1999,
§7 (prediction-error methods) and §4.2 (output-error models); T. McKelvey, A. Helmersson,
T. Ribarits, "Data driven local coordinates for multivariable linear systems and their
application to system identification", Automatica 40(9), 2004.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset, Experiment
from tendonkit.errors import DataError, OptionError, TendonkitError
from tendonkit.hookspecs import hookimpl
from tendonkit.identification import (
    build_model,
    is_int,
    one_blas_thread,
    options_dict,
    require_samples,
    training_fit,
    without_training_fit,
)
from tendonkit.plugins import _innovation, _modal
from tendonkit.plugins._arx_structure import estimate_delays
from tendonkit.plugins.arx import ARX as ArxOptions
from tendonkit.plugins.n4sid import N4SID
from tendonkit.schema import Block, StateSpace
from tendonkit.simulate import estimate_x0, ss_response, transform_inputs

FloatArray = NDArray[np.float64]

#: Largest pole modulus of a stable mode.
STABLE_RADIUS = _modal.STABLE_RADIUS
#: Largest delay ``delayest`` tries for ``pem``.  pem keeps the delays it finds (no scoring
#: with and without them, as ARX's automatic structure does), and on a lightly damped plant
#: with several outputs delayest's minimum can fall anywhere (25-71 samples on a three-mass
#: chain with no dead time; docs/identification.md): the ARX's ``max_delay="auto"`` (up to
#: 160) would hand such a delay to every model.
MAX_DELAY = 10
#: A smaller candidate within this relative margin of the best held-out error is preferred
#: (a tie: the candidates are refined to SELECTION_TOL only).
PARSIMONY = 0.001
#: Higher orders of a family are not tried after STOP_AFTER consecutive candidates whose
#: held-out error exceeds STOP_FACTOR times the family's best (they diverge, not improve).
STOP_FACTOR = 10.0
STOP_AFTER = 2
#: Tolerance (and at most 50 evaluations) of the candidates' refinements: ranking them needs
#: their errors to a few per cent, not the final model's convergence.
SELECTION_TOL = 1e-5
#: The criteria the refinement can minimise (``PEM.focus``).
FOCUSES = ("simulation", "prediction")


@dataclass(frozen=True, kw_only=True)
class PEM:
    """Options of the prediction-error identifier.

    Parameters
    ----------
    order : int or None
        Number of states (integrators included); ``None`` selects it on held-out data.
    max_order : int
        Largest order tried by the selection.
    integrator : bool or None
        One pure integrator per output (an integrating plant: a position driven by a
        force); ``None`` tries both and keeps the better on held-out data.
    offset : bool
        Estimate the operating point: ``y0`` (and ``u0`` with integrators, which would
        otherwise drift), stored in the model and undone in simulation.
    feedthrough : bool or None
        Estimate ``D``; ``False``: ``D = 0``; ``None`` (default): estimate it when some input
        acts without delay, as MATLAB's ``delayest`` finds it (ARX(2, 2) models with delays
        0 … :data:`MAX_DELAY` of every input; :func:`tendonkit.plugins._arx_structure.estimate_delays`).
    delay : bool or None
        ``None`` (default) or ``True``: every input's delay is estimated (``delayest``, as
        for ``feedthrough``) and a delay beyond one sample becomes an input ``delay`` block
        of the model — a dead time costs no states and no parameters; ``False``: none.
    folds : int
        Blocks every experiment is cut into for the structure selection's cross-validation.
    init_window : int
        Samples from which the initial state of a held-out block is estimated before it is
        scored (the benchmarks' protocol; short windows penalise states the data cannot fix).
    max_iterations : int
        Cap on the refinement's function evaluations (each also computes the Jacobian).
    focus : str
        ``"simulation"`` (default): the free-run simulation error, no noise model (an
        output-error model, the criterion the benchmarks judge).  ``"prediction"``: then the
        innovation form — ``A, B, C, D``, the Kalman gain ``K``, the initial states and the
        operating point — refitted by the ``horizon``-step prediction error (MATLAB
        ``ssest``'s default focus; the maximum-likelihood fit under process noise, and the
        model a state estimator or an MPC predicts with).  The structure is selected as for
        simulation.
    horizon : int
        Prediction horizon in samples of ``focus="prediction"`` (1: the one-step error).

    Examples
    --------
    >>> from tendonkit.testsystems import random_state_space, simulate_truth
    >>> data, _ = simulate_truth(random_state_space(3, 1, 1, seed=3), 1000, noise=0.0)
    >>> model = PEM(order=3, integrator=False).identify(data)
    >>> model.representation.n_states, round(model.provenance.training_fit["y1"], 4)
    (3, 100.0)
    """

    name: ClassVar[str] = "pem"
    description: ClassVar[str] = (
        "Prediction-error (output-error) state space: n4sid start, simulation-error "
        "refinement of all matrices, initial states and offsets; order and integrators "
        "selected on held-out data."
    )

    order: int | None = None
    max_order: int = 8
    integrator: bool | None = None
    offset: bool = True
    feedthrough: bool | None = None
    delay: bool | None = None
    folds: int = 4
    init_window: int = 10
    max_iterations: int = 100
    focus: str = "simulation"
    horizon: int = 1

    def __post_init__(self) -> None:
        p: list[str] = []
        if self.order is not None and (not is_int(self.order) or self.order < 1):
            p.append(f"order must be an integer >= 1 or None (automatic), found {self.order!r}.")
        if not is_int(self.max_order) or self.max_order < 1:
            p.append(f"max_order must be an integer >= 1, found {self.max_order!r}.")
        if self.integrator is not None and not isinstance(self.integrator, bool | np.bool_):
            p.append(
                f"integrator must be true, false or None (automatic), found {self.integrator!r}."
            )
        if self.delay is not None and not isinstance(self.delay, bool | np.bool_):
            p.append(f"delay must be true, false or None (automatic), found {self.delay!r}.")
        if not isinstance(self.offset, bool | np.bool_):
            p.append(f"offset must be true or false, found {self.offset!r}.")
        if self.feedthrough is not None and not isinstance(self.feedthrough, bool | np.bool_):
            p.append(
                f"feedthrough must be true, false or None (automatic), found {self.feedthrough!r}."
            )
        if not is_int(self.folds) or self.folds < 2:
            p.append(f"folds must be an integer >= 2, found {self.folds!r}.")
        if not is_int(self.init_window) or self.init_window < 1:
            p.append(f"init_window must be an integer >= 1, found {self.init_window!r}.")
        if not is_int(self.max_iterations) or self.max_iterations < 1:
            p.append(f"max_iterations must be an integer >= 1, found {self.max_iterations!r}.")
        if self.focus not in FOCUSES:
            p.append(f"focus must be one of {', '.join(FOCUSES)}, found {self.focus!r}.")
        if not is_int(self.horizon) or self.horizon < 1:
            p.append(f"horizon must be an integer >= 1, found {self.horizon!r}.")
        elif self.horizon != 1 and self.focus != "prediction":
            p.append(
                f"horizon {self.horizon} applies to focus='prediction' only (the simulation "
                "error has no horizon)."
            )
        if p:
            raise OptionError("Invalid options for pem:", p)

    # ------------------------------------------------------------------------------------
    def identify(self, dataset: Dataset) -> Any:
        """Identify a state-space model from ``dataset`` (all experiments)."""
        with one_blas_thread():
            if self.feedthrough is not None and self.delay is False:
                return self._identify(dataset)
            # the delay of every input, as MATLAB's delayest finds it
            delays, record = estimate_delays(ArxOptions(max_delay=MAX_DELAY), dataset)
            feedthrough = (0 in delays) if self.feedthrough is None else self.feedthrough
            # a delay beyond the one sample a strictly proper model has becomes a delay block
            extra = [max(d - 1, 0) if self.delay is not False else 0 for d in delays]
            blocks = tuple(
                Block("delay", name, {"samples": float(d)})
                for name, d in zip(dataset.inputs, extra, strict=True)
                if d > 0
            )
            shifted = transform_inputs(dataset, blocks) if blocks else dataset
            model = dataclasses.replace(self, feedthrough=feedthrough)._identify(shifted)
            if blocks:
                model = model.replace(input_blocks=blocks)
            prov = model.provenance
            note = (
                f"input delays {list(delays)} (delayest): feedthrough "
                f"{'estimated' if feedthrough else 'none'}"
                + (f", delay blocks {[b.params['samples'] for b in blocks]}" if blocks else "")
            )
            fit = training_fit(model, dataset) if prov.training_fit else prov.training_fit
            return model.replace(
                provenance=dataclasses.replace(
                    prov,
                    options=options_dict(self),
                    dataset_hash=dataset.hash(),
                    training_fit=fit,
                    notes="; ".join(x for x in (prov.notes, note) if x),
                    details={**prov.details, "delays": record},
                )
            )

    def _candidates(self, ny: int) -> list[tuple[int, bool]]:
        orders = [self.order] if self.order is not None else range(1, self.max_order + 1)
        integ = [self.integrator] if self.integrator is not None else [False, True]
        return [(n, i) for i in integ for n in orders if not i or n > ny]

    def _identify(self, dataset: Dataset) -> Any:
        ny = dataset.ny
        require_samples(dataset, 20, "pem")
        candidates = self._candidates(ny)
        if not candidates:
            raise OptionError(
                f"pem: order {self.order} leaves no state besides the {ny} integrator(s); "
                f"use order >= {ny + 1}."
            )
        shortest = min(e.n_samples for e in dataset.experiments)
        if self.focus == "prediction" and self.horizon >= shortest // 2:
            raise OptionError(
                f"pem: horizon {self.horizon} leaves too few samples to predict in the "
                f"shortest experiment ({shortest}); use horizon < {max(shortest // 2, 1)}."
            )
        exps = [(e.u, e.y) for e in dataset.experiments]
        sy = np.std(np.vstack([y for _, y in exps]), axis=0)
        sy[~(sy > 0)] = 1.0
        table: list[dict[str, Any]] = []
        if len(candidates) == 1:
            (n, integ), start = candidates[0], None
        else:
            n, integ, start = self._select(dataset, candidates, sy, table)
        if start is None:
            try:
                start = self._start(dataset, n, integ)
            except np.linalg.LinAlgError as exc:
                raise DataError(
                    f"pem: no start for order {n}{' with integrators' if integ else ''}: the "
                    f"subspace model is singular ({exc}); try another order, or integrator="
                    f"{not integ}."
                ) from None
        layout, theta = start
        theta, cost0, cost, nfev = _modal.refine(layout, theta, exps, sy, self.max_iterations)
        how = "given" if len(candidates) == 1 else "selected on held-out data"
        notes = [
            f"order {n}{' with ' + str(ny) + ' integrator(s)' if integ else ''} ({how})",
            f"simulation-error refinement: normalised RMS {cost0:.4g} -> {cost:.4g} "
            f"({nfev} evaluations)",
        ]
        refined = None
        if self.focus == "prediction":
            starts = _innovation.initial_gains(layout, theta, exps)
            refined = _innovation.refine(
                layout, theta, starts, exps, sy, self.horizon, self.max_iterations
            )
            theta = refined.theta
            notes.append(
                f"{self.horizon}-step prediction-error refinement with the Kalman gain K: "
                f"normalised RMS {refined.before:.4g} -> {refined.after:.4g} "
                f"({refined.evaluations} evaluations)"
                + ("" if refined.jacobian is not None else "; no lower error found: K is the "
                   "start's Kalman gain and no covariance is stored")
                + ("" if self.horizon == 1 else "; no covariance stored (errors several steps "
                   "ahead are correlated)")
            )  # fmt: skip
        A, B, C, D, x0s, u0, y0 = _modal.to_state_space(layout, theta)
        rep = StateSpace(
            A=A,
            B=B,
            C=C,
            D=D,
            K=None if refined is None else refined.K,
            x0=x0s[0],
            u0=u0 if (self.offset and integ) else None,
            y0=y0 if (self.offset and not integ) else None,
        )
        details: dict[str, Any] = {"candidates": table} if table else {}
        if refined is None:
            cov = _covariance(layout, theta, exps, sy, rep)
        elif self.horizon == 1:
            cov = _innovation.covariance(layout, refined, rep)
        else:
            cov = None
        if cov is not None:
            details["covariance"] = cov
        return build_model(self, dataset, rep, notes="; ".join(notes), details=details or None)

    # ------------------------------------------------------------------------------------
    def _start(self, data: Dataset, n: int, integ: bool) -> tuple[_modal.Layout, FloatArray]:
        """The subspace model of order ``n`` (see the module notes), in modal coordinates."""
        nu, ny = data.nu, data.ny
        um = np.mean(np.vstack([e.u for e in data.experiments]), axis=0)
        if not integ:
            ym = np.mean(np.vstack([e.y for e in data.experiments]), axis=0)
            if not self.offset:
                um, ym = np.zeros(nu), np.zeros(ny)
            centred = data.with_experiments(
                [Experiment(t=e.t, u=e.u - um, y=e.y - ym, name=e.name) for e in data.experiments]
            )
            with without_training_fit():
                rep = N4SID(order=n, feedthrough=self.feedthrough).identify(centred).representation
            A, B, C, D = rep.A, rep.B, rep.C, rep.D
            # the centred inputs are deviations from um: fold it into y0 (stable A)
            y0 = ym - (C @ np.linalg.solve(np.eye(n) - A, B) + D) @ um if self.offset else ym
            x0s = [np.zeros(n) for _ in data.experiments]
            layout, theta = _modal.from_state_space(
                A, B, C, D, x0s, integrators=0, feedthrough=self.feedthrough,
                output_offset=self.offset, input_offset=False, y0=y0, u0=np.zeros(nu),
                radius=STABLE_RADIUS,
            )  # fmt: skip
        else:
            dy = [np.diff(e.y, axis=0) for e in data.experiments]
            vm = np.mean(np.vstack(dy), axis=0)
            velocity = data.with_experiments(
                [
                    Experiment(t=e.t[:-1], u=e.u[:-1] - um, y=d - vm, name=e.name)
                    for e, d in zip(data.experiments, dy, strict=True)
                ]
            )
            n1 = n - ny
            with without_training_fit():
                rep = N4SID(order=n1, feedthrough=True).identify(velocity).representation
            A1, B1, C1, D1 = rep.A, rep.B, rep.C, rep.D
            gain = C1 @ np.linalg.solve(np.eye(n1) - A1, B1) + D1
            # u0 where the mean velocity is zero: gain (um - u0) = vm
            u0 = um - np.linalg.lstsq(gain, vm, rcond=None)[0] if self.offset else np.zeros(nu)
            A = np.block([[A1, np.zeros((n1, ny))], [C1, np.eye(ny)]])
            B = np.vstack([B1, D1])
            C = np.hstack([np.zeros((ny, n1)), np.eye(ny)])
            x0s = [np.concatenate([np.zeros(n1), e.y[0]]) for e in data.experiments]
            layout, theta = _modal.from_state_space(
                A, B, C, np.zeros((ny, nu)), x0s, integrators=ny,
                feedthrough=self.feedthrough, output_offset=False, input_offset=self.offset,
                y0=np.zeros(ny), u0=u0, radius=STABLE_RADIUS,
            )  # fmt: skip
        exps = [(e.u, e.y) for e in data.experiments]
        theta = _fit_initial_states(layout, theta, exps)
        return layout, theta

    def _select(
        self,
        data: Dataset,
        candidates: list[tuple[int, bool]],
        sy: FloatArray,
        table: list[dict[str, Any]],
    ) -> tuple[int, bool, None]:
        """Blocked cross-validation: each candidate refined without one block, scored on it."""
        # lazy: heavy (tqdm)
        from tqdm import tqdm

        folds = _folds(data, self.folds, self.init_window)
        # every candidate is identified once per fold: minutes on long records, so a bar
        # (tqdm's own rule: shown on a terminal, silent in pipes, logs and tests)
        bar = tqdm(
            total=len(candidates) * len(folds), desc="pem: structure selection", unit="fit",
            disable=None, leave=False,
        )  # fmt: skip
        rows: list[tuple[float, int, int, bool]] = []
        family_best: dict[bool, float] = {}
        worse: dict[bool, int] = {}
        slow: dict[int, float] = {}  # stable candidates: the largest pole modulus over folds
        shortest = min(e.n_samples for e in data.experiments)
        screened: str | None = None
        for n, integ in candidates:
            if integ and self.integrator is None and screened is None:
                screened = _integrator_screen(rows, slow, shortest)
            if worse.get(integ, 0) >= STOP_AFTER or (integ and screened):
                why = screened if integ and screened else "higher orders diverged"
                table.append({"order": n, "integrator": integ, "skipped": why})
                bar.update(len(folds))
                continue
            bar.set_postfix_str(f"order {n}{' + integrator' if integ else ''}")
            try:
                sq, count, est = 0.0, 0, []
                for fit_data, held in folds:
                    layout, theta = self._start(fit_data, n, integ)
                    exps = [(e.u, e.y) for e in fit_data.experiments]
                    theta, _, cost, _ = _modal.refine(
                        layout, theta, exps, sy, min(self.max_iterations, 50), SELECTION_TOL
                    )
                    est.append(cost)
                    if not integ:
                        radius = float(np.max(np.abs(_modal.decode(layout, theta).p), initial=0))
                        slow[n] = max(slow.get(n, 0.0), radius)
                    e2, c = _held_out(layout, theta, held, sy, self.init_window)
                    sq, count = sq + e2, count + c
                    bar.update()
            except (TendonkitError, np.linalg.LinAlgError) as exc:
                table.append({"order": n, "integrator": integ, "error": str(exc).splitlines()[0]})
                continue
            val = float(np.sqrt(sq / count)) if np.isfinite(sq) else np.inf
            row = {
                "order": n,
                "integrator": integ,
                "parameters": layout.size - layout.n_exp * layout.n_states,
                "estimation_rms": float(np.mean(est)),
                "held_out_rms": val,
            }
            table.append(row)
            rows.append((val, row["parameters"], n, integ))
            # higher orders of a family stop once two in a row are far worse than its best
            best_so_far = family_best.get(integ, np.inf)
            family_best[integ] = min(best_so_far, val)
            far = not val <= STOP_FACTOR * family_best[integ]
            worse[integ] = worse.get(integ, 0) + 1 if far else 0
        bar.close()
        if not rows:
            raise OptionError(
                "pem: no candidate structure could be identified:",
                [f"order {r['order']}: {r['error']}" for r in table],
            )
        top = min(r[0] for r in rows)
        eligible = [r for r in rows if r[0] <= top * (1.0 + PARSIMONY)]
        _, _, n, integ = min(eligible, key=lambda r: (r[1], r[0]))
        for row in table:
            row["selected"] = row.get("order") == n and row.get("integrator") == integ
        return n, integ, None


def _integrator_screen(
    rows: list[tuple[float, int, int, bool]], slow: dict[int, float], length: int
) -> str | None:
    """Why integrators need not be tried, or ``None`` when they must.

    A pole whose mode has not decayed to 1/e over the shortest record cannot be told from an
    integrator by these data; only then is an integrating structure a candidate.  The best
    stable candidate is asked (its slowest pole over the folds).
    """
    stable = [r for r in rows if not r[3]]
    if not stable:
        return None
    best = min(stable, key=lambda r: r[0])
    radius = slow.get(best[2], 1.0)
    if radius <= 0.0 or radius**length < np.exp(-1.0):
        return (
            f"not tried: the best stable model's slowest mode (pole {radius:.6g}) decays "
            f"within the {length}-sample record"
        )
    return None


def _folds(data: Dataset, k: int, window: int) -> list[tuple[Dataset, list[Experiment]]]:
    """:meth:`Dataset.blocked_folds`, held-out blocks long enough to score after the window."""
    out = [(f, list(h.experiments)) for f, h in data.blocked_folds(k, 2 * window + 1, 20)]
    if not out:
        raise OptionError(
            f"pem: the experiments are too short to hold out blocks of {k} folds with an "
            f"initialisation window of {window} samples; give the order and integrator."
        )
    return out


def _held_out(
    layout: _modal.Layout,
    theta: FloatArray,
    held: list[Experiment],
    sy: FloatArray,
    window: int,
) -> tuple[float, int]:
    """Sum of squared normalised errors (and their count) on the held-out blocks, each
    simulated from the state estimated on its first ``window`` samples (the benchmark way)."""
    A, B, C, D, _, u0, y0 = _modal.to_state_space(layout, theta)
    rep = StateSpace(A=A, B=B, C=C, D=D, u0=u0, y0=y0)
    sq, count = 0.0, 0
    with np.errstate(all="ignore"):
        for e in held:
            x0 = estimate_x0(rep, e.u, e.y, window=window)
            sim = ss_response(A, B, C, D, e.u - u0, x0) + y0
            err = (e.y[window:] - sim[window:]) / sy
            sq += float(np.sum(err**2))
            count += err.size
    return (sq if np.isfinite(sq) else np.inf), count


# -- the refinement -------------------------------------------------------------------------------


def _fit_initial_states(
    layout: _modal.Layout, theta: FloatArray, exps: list[tuple[FloatArray, FloatArray]]
) -> FloatArray:
    """Linear least squares for the initial states and offsets, all else fixed."""
    sl = layout.slices
    cols = [i for s in sl["s0"] + sl["y0"] for i in range(s.start, s.stop)]
    if not cols:
        return theta
    theta = theta.copy()
    J = np.vstack(
        [
            _modal.jacobian(layout, theta, u, k).reshape(-1, layout.size)
            for k, (u, _) in enumerate(exps)
        ]
    )[:, cols]
    r = np.concatenate(
        [(y - _modal.simulate(layout, theta, u, k)).ravel() for k, (u, y) in enumerate(exps)]
    )
    step, *_ = np.linalg.lstsq(J, r, rcond=None)
    if np.all(np.isfinite(step)):
        theta[cols] += step
    return theta


def _covariance(
    layout: _modal.Layout,
    theta: FloatArray,
    exps: list[tuple[FloatArray, FloatArray]],
    sy: FloatArray,
    rep: StateSpace,
) -> dict[str, Any] | None:
    """Gauss–Newton covariance ``λ (JᵀJ)⁺`` mapped to the entries of ``rep`` that vary.

    ``J`` is the Jacobian of the normalised simulation errors at the optimum and ``λ`` their
    variance (:func:`tendonkit.plugins._modal.entry_covariance` maps it; the initial states
    are left out).
    """
    J = _modal.residual_jacobian(layout, theta, exps, sy)
    r = _modal.residuals(layout, theta, exps, sy)
    gn = _modal.gauss_newton_covariance(J, r)
    if gn is None:
        return None
    return _modal.entry_covariance(layout, theta, gn[0], gn[1], rep)


@hookimpl
def tendonkit_register_identifiers(registry):  # type: ignore[no-untyped-def]
    """Register the prediction-error identifier."""
    registry.add(PEM)
