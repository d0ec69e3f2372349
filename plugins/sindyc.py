"""SINDYc: sparse identification of nonlinear dynamics with control, in discrete time.

The state is the vector of measured outputs and the model is the one-step map

``x[k+1] = Ξᵀ Θ(x[k], u[k])``,  ``y[k] = x[k]``,

with the candidate library Θ of the paper: every monomial of the states and inputs up to
``degree`` (so ``x·u`` cross terms for degree 2), the constant, and ``sin`` of every state.
Ξ is found by pysindy's ``DiscreteSINDy`` with the sequentially thresholded least-squares
optimizer ``STLSQ`` (threshold λ).  Each experiment is passed to pysindy as a trajectory of its
own, so the last sample of one experiment never "predicts" the first of the next.

Normalisation.  The robot's inputs are forces of 20–190 N and its outputs angles of about
0.3 rad, so a threshold on raw coefficients would compare numbers in incompatible units.
With ``normalize=True`` every signal ``s`` is replaced by ``z = (s - mean) * (1/std)`` before
the regression (the target too; mean and 1/std of the data the model is fitted on, rounded to
six significant digits), and the result is folded back exactly: each factor of a
term carries the same ``offset`` and ``scale`` (:class:`~tendonkit.terms.Factor`), and each
state's coefficients are divided by that state's scale, the state's mean being added to the
constant term.  The saved model therefore reads and writes raw signals.  Polynomials keep
their span under this affine change of variables; ``sin`` acts on the normalised state,
``sin((x - mean) / std)``.

Threshold sweep.  Without an explicit ``threshold``, λ is chosen on a validation split (the
last ``validation_fraction`` of every experiment): first over the powers of ten
:data:`COARSE_THRESHOLDS`, then over :data:`FINE_STEPS` geometric steps per decade around the
best coarse value.  Each candidate is scored by the free-run simulation fit of its model on the
validation split (initial state = first measured sample, as in
:func:`tendonkit.simulate.simulate`); a candidate whose simulation diverges scores ``-inf``.
Among the candidates within :data:`TIE_TOLERANCE` of the best score the largest λ (the
sparsest model) wins.  The returned model is the validated candidate itself, fitted on the
first part of every experiment: STLSQ's support can change abruptly with the data, so a refit
on all the data would not be the model that was scored.  The chosen λ and every score are
recorded in the provenance notes (``threshold=...`` first); identifying again with that
threshold fits on all the data instead.

The model holds no pysindy object: the library is rebuilt as structured
:class:`~tendonkit.terms.Term` objects in pysindy's feature order, and the correspondence is
verified numerically against the library matrix pysindy regressed on before the model is made.

Examples
--------
>>> SINDYc(threshold=0.0035, degree=2).threshold
0.0035
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import warnings
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset, Experiment
from tendonkit.errors import DataError, OptionError, PluginError
from tendonkit.hookspecs import hookimpl
from tendonkit.identification import build_model, is_int, require_samples, signals
from tendonkit.metrics import fit
from tendonkit.parallel import map_tasks
from tendonkit.regression import r_factor
from tendonkit.schema import Model, SparseMap
from tendonkit.terms import CompiledTerms, Factor, Term

FloatArray = NDArray[np.float64]

#: Coarse threshold grid (normalised units when ``normalize=True``): powers of ten.
COARSE_THRESHOLDS: tuple[float, ...] = tuple(float(f"1e{e}") for e in range(-6, 1))
#: Geometric steps per decade of the fine sweep, which spans one decade each side.
FINE_STEPS = 10
#: Candidates whose validation fit is within this many percentage points of the best are tied;
#: the largest threshold among them (the sparsest model) is chosen.
TIE_TOLERANCE = 1e-6
#: A candidate whose simulated state leaves this many standard deviations of the training data
#: (or becomes NaN/inf) has diverged and scores ``-inf``.
DIVERGENCE_BOUND = 1e6
#: Largest polynomial degree accepted (the library grows combinatorially).
MAX_DEGREE = 5
#: Relative tolerance of the term-by-term comparison with pysindy's library matrix.
VERIFY_RTOL = 1e-9


@dataclass(frozen=True, kw_only=True)
class SINDYc:
    """Options of the SINDYc identifier (discrete-time SINDy with control, pysindy STLSQ).

    Parameters
    ----------
    threshold : float or None
        STLSQ threshold λ (>= 0), in normalised units when ``normalize`` is true.  ``None``
        sweeps it on a validation split (module docstring); the paper found 0.0035.
    degree : int
        Largest total degree of the monomials in states and inputs, 1 to ``MAX_DEGREE``.
    sin : bool
        Add ``sin`` of every state to the library.
    alpha : float
        Ridge weight of STLSQ's thresholding iterations (>= 0; pysindy's default).  It only
        steers which terms survive: the final coefficients are refitted without it on the
        selected terms (pysindy's ``unbias``).  0 gives plain thresholded least squares.
    max_iter : int
        Largest number of STLSQ iterations (>= 1).
    validation_fraction : float
        Share of every experiment, at its end, held out to score the threshold sweep, in (0, 1).
    normalize : bool
        Regress on mean/std-normalised signals and fold the normalisation into the terms.
    jobs : int
        Worker processes fitting the sweep's thresholds (:mod:`tendonkit.parallel`); 1
        (default) fits them here: each fit takes milliseconds, less than starting a worker
        (benchmarks/README.md, "Sweeps").  The result does not depend on it.

    Examples
    --------
    >>> SINDYc(degree=1, sin=False).degree
    1
    """

    name: ClassVar[str] = "sindyc"
    description: ClassVar[str] = (
        "Discrete-time SINDy with control (pysindy, STLSQ): polynomials of x, u up to degree 2 "
        "and sin(x); threshold swept on a validation split."
    )

    threshold: float | None = None
    degree: int = 2
    sin: bool = True
    alpha: float = 0.05
    max_iter: int = 20
    validation_fraction: float = 0.2
    normalize: bool = True
    jobs: int = 1

    def __post_init__(self) -> None:
        p = []
        if not is_int(self.jobs) or self.jobs < 1:
            p.append(f"jobs must be an integer >= 1, found {self.jobs!r}.")
        if self.threshold is not None and not (_is_number(self.threshold) and self.threshold >= 0):
            p.append(f"threshold must be a number >= 0 or None (sweep), found {self.threshold!r}.")
        if not is_int(self.degree) or not 1 <= self.degree <= MAX_DEGREE:
            p.append(f"degree must be an integer from 1 to {MAX_DEGREE}, found {self.degree!r}.")
        if not isinstance(self.sin, bool):
            p.append(f"sin must be true or false, found {self.sin!r}.")
        if not (_is_number(self.alpha) and self.alpha >= 0):
            p.append(f"alpha must be a number >= 0, found {self.alpha!r}.")
        if not is_int(self.max_iter) or self.max_iter < 1:
            p.append(f"max_iter must be an integer >= 1, found {self.max_iter!r}.")
        frac = self.validation_fraction
        if not (_is_number(frac) and 0.0 < frac < 1.0):
            p.append(f"validation_fraction must be a number in (0, 1), found {frac!r}.")
        if not isinstance(self.normalize, bool):
            p.append(f"normalize must be true or false, found {self.normalize!r}.")
        if p:
            raise OptionError("Invalid options for sindyc:", p)

    def identify(self, dataset: Dataset) -> Model:
        """Identify a ``sparse_map`` model whose states are the outputs of ``dataset``.

        Parameters
        ----------
        dataset : Dataset
            Training data; every experiment is a separate trajectory.

        Returns
        -------
        Model
            States named like the outputs, ``output_states = (0, ..., ny-1)``; terms whose
            coefficients are all zero are left out.

        Raises
        ------
        DataError
            If an experiment is too short or there are fewer regression rows than terms.
        PluginError
            If pysindy's library does not match the structured terms (a pysindy change).
        """
        nx = dataset.ny
        n_terms = math.comb(nx + dataset.nu + self.degree, self.degree) + (nx if self.sin else 0)
        sweep: list[tuple[float, float]] = []
        if self.threshold is None:
            fit_data, valid = self._split(dataset)
        else:
            fit_data = dataset
        _require_rows(fit_data, n_terms)
        norm = _Normalisation.of(fit_data, self.normalize)
        terms = library_terms(
            dataset.outputs, dataset.inputs, norm.offset, norm.scale, self.degree, self.sin
        )
        if self.threshold is None:
            lam, sweep = self._sweep(fit_data, valid, norm, terms)
        else:
            lam = float(self.threshold)
        coef = self._fit(fit_data, norm, lam, terms)
        keep = np.any(coef != 0.0, axis=1)
        rep = SparseMap(
            terms=tuple(t for t, k in zip(terms, keep) if k),
            coefficients=coef[keep],
            output_states=tuple(range(nx)),
        )
        notes = self._notes(lam, sweep, int(keep.sum()), len(terms))
        states = signals(dataset.outputs, dataset.units)
        # a diverging candidate scored -inf: stored as null (model files hold finite numbers)
        details = {
            "threshold": lam,
            "sweep": [[float(a), float(b) if np.isfinite(b) else None] for a, b in sweep],
        }
        return build_model(self, dataset, rep, states=states, notes=notes, details=details)

    # -- steps ---------------------------------------------------------------------------------
    def _split(self, dataset: Dataset) -> tuple[Dataset, Dataset]:
        """Training and validation parts; every part needs two samples (one transition)."""
        f = float(self.validation_fraction)
        needed = 2
        while round((1.0 - f) * needed) < 2 or needed - round((1.0 - f) * needed) < 2:
            needed += 1
        require_samples(
            dataset,
            needed,
            f"the threshold sweep with validation_fraction={f:g} (or give threshold)",
        )
        return dataset.split(1.0 - f)

    def _optimizer(self, lam: float, initial_guess: FloatArray | None = None) -> Any:
        # lazy: heavy (pysindy)
        import pysindy as ps

        return ps.STLSQ(
            threshold=lam,
            alpha=float(self.alpha),
            max_iter=int(self.max_iter),
            initial_guess=initial_guess,
        )

    def _fit(
        self, data: Dataset, norm: _Normalisation, lam: float, terms: Sequence[Term]
    ) -> FloatArray:
        """Raw-unit coefficients of ``DiscreteSINDy.fit`` with threshold ``lam``, compressed.

        pysindy's ``STLSQ`` runs on pysindy's library matrix Θ reduced by one QR factorisation
        (``||Y - Θξ||² = ||QᵀY - Rξ||² + const`` for every support, ridge term included), the
        regression of :meth:`_sweep`: the coefficients of :meth:`_pysindy_fit` (tested to
        1e-12) at a fraction of its cost on long records.  The structured terms are checked
        against pysindy's library on the first rows of every experiment.
        """
        theta = library_matrix(data, norm, self.degree, self.sin)
        # the structured terms against pysindy's rows of the first samples of every experiment
        lengths = [e.n_samples - 1 for e in data.experiments]
        starts = np.cumsum([0, *lengths[:-1]])
        rows = np.concatenate(
            [
                np.arange(a, a + min(n, VERIFY_ROWS - 1))
                for a, n in zip(starts, lengths, strict=True)
            ]
        )
        head = data.with_experiments(_head(e, VERIFY_ROWS) for e in data.experiments)
        verify_terms(terms, theta[rows], head)
        target = np.vstack([norm.states(e.y)[1:] for e in data.experiments])
        k = theta.shape[1]
        rq = r_factor(np.hstack([theta, target]))  # [R, QᵀY]: Q itself is never formed
        r, qy = rq[:k, :k], rq[:k, k:]
        guess, *_ = np.linalg.lstsq(r, qy, rcond=None)  # pysindy's initial guess, same system
        opt = self._optimizer(lam, initial_guess=guess.T.copy())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            opt.fit(r, qy)
        return norm.fold(np.asarray(opt.coef_, dtype=float))

    def _pysindy_fit(self, data: Dataset, norm: _Normalisation, lam: float) -> Any:
        """Fit ``ps.DiscreteSINDy`` on the normalised experiments, one trajectory each."""
        # lazy: heavy (pysindy)
        import pysindy as ps

        xs = [norm.states(e.y) for e in data.experiments]
        us = [norm.inputs(e.u) for e in data.experiments] if norm.nu else None
        model = ps.DiscreteSINDy(
            optimizer=self._optimizer(lam),
            feature_library=_library(norm.nx, norm.nu, self.degree, self.sin),
        )
        with warnings.catch_warnings():
            # "Sparsity parameter is too big" and non-convergence are expected during a sweep.
            warnings.simplefilter("ignore")
            model.fit(xs, t=float(data.dt), u=us)
        return model

    def _sweep(
        self, train: Dataset, valid: Dataset, norm: _Normalisation, terms: Sequence[Term]
    ) -> tuple[float, list[tuple[float, float]]]:
        """Coarse then fine threshold sweep; returns the chosen λ and ``(λ, score)`` pairs.

        Every candidate runs pysindy's ``STLSQ`` on pysindy's library matrix Θ of the training
        part, compressed by a QR factorisation ``Θ = QR``: ``||Y - Θξ||² = ||QᵀY - Rξ||² +
        const`` for every support, ridge term included, so STLSQ on ``(R, QᵀY)`` gives the
        coefficients of ``DiscreteSINDy.fit`` at a fraction of the cost.
        """
        theta = library_matrix(train, norm, self.degree, self.sin)
        target = np.vstack([norm.states(e.y)[1:] for e in train.experiments])
        k = theta.shape[1]
        rq = r_factor(np.hstack([theta, target]))  # [R, QᵀY]: Q itself is never formed
        r, qy = rq[:k, :k], rq[:k, k:]
        guess, *_ = np.linalg.lstsq(r, qy, rcond=None)  # pysindy's initial guess, same system
        scores: dict[float, float] = {}

        def run(lams: Sequence[float]) -> None:
            lams = [lam for lam in lams if lam not in scores]
            # independent fits: self.jobs workers run them (tendonkit.parallel)
            fitted = map_tasks(_stlsq, lams, shared=(self, r, qy, guess), jobs=self.jobs)
            coefs = [norm.fold(c) for c in fitted]
            for lam, s in zip(lams, free_run_scores(terms, np.array(coefs), valid, norm)):
                scores[lam] = float(s)

        run(COARSE_THRESHOLDS)
        coarse = _best(scores)
        steps = range(-FINE_STEPS + 1, FINE_STEPS)
        run([float(f"{coarse * 10 ** (k / FINE_STEPS):.3g}") for k in steps])
        return _best(scores), sorted(scores.items())

    def _notes(self, lam: float, sweep: list[tuple[float, float]], n_kept: int, n_lib: int) -> str:
        units = "normalised" if self.normalize else "raw"
        head = f"threshold={lam!r} ({units} units); {n_kept} of {n_lib} library terms kept."
        if not sweep:
            return f"{head} Threshold given (no sweep); fitted on all the data."
        table = ", ".join(f"{lam_:.3g}: {s:.4f}" for lam_, s in sweep)
        share = f"{self.validation_fraction:.0%}"
        return (
            f"{head} Threshold chosen by free-run fit on the last {share} of each experiment; "
            f"the model is the candidate fitted on the rest. Swept threshold -> mean validation "
            f"fit [%]: {table}."
        )


# -- library --------------------------------------------------------------------------------------


def _stlsq(shared: tuple[Any, ...], lam: float) -> FloatArray:
    """STLSQ coefficients of one threshold on the compressed system ``(R, QᵀY)``."""
    ident, r, qy, guess = shared
    opt = ident._optimizer(lam, initial_guess=guess.T.copy())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        opt.fit(r, qy)
    return np.asarray(opt.coef_, dtype=float)


def library_terms(
    states: Sequence[str],
    inputs: Sequence[str],
    offset: FloatArray,
    scale: FloatArray,
    degree: int,
    sin: bool,
) -> list[Term]:
    """The SINDYc library as structured terms, in pysindy's feature order.

    Monomials of ``(*states, *inputs)`` of total degree 0..``degree`` in the order of
    ``PolynomialLibrary`` (scikit-learn's ``combinations_with_replacement`` per degree), then
    ``sin`` of each state (``FourierLibrary`` with one frequency and no cosine).  Signal ``i``
    enters as ``(s - offset[i]) * scale[i]``.

    Parameters
    ----------
    states, inputs : sequence of str
        State and input names (the order of the columns given to pysindy).
    offset, scale : array (n_states + n_inputs,)
        Normalisation of every signal.
    degree : int
        Largest total degree.
    sin : bool
        Append ``sin`` of every state.

    Returns
    -------
    list of Term
        The library; the first term is the constant.

    Examples
    --------
    >>> ts = library_terms(["x"], ["u"], np.zeros(2), np.ones(2), 2, True)
    >>> [t.label for t in ts]
    ['1', 'x', 'u', 'x^2', 'x*u', 'u^2', 'sin(x)']
    """
    names = [*states, *inputs]
    base = [Factor(n, scale=float(scale[i]), offset=float(offset[i])) for i, n in enumerate(names)]
    terms = []
    for d in range(degree + 1):
        for combo in itertools.combinations_with_replacement(range(len(names)), d):
            counts = sorted(Counter(combo).items())
            terms.append(Term(tuple(dataclasses.replace(base[i], power=p) for i, p in counts)))
    if sin:
        terms.extend(Term((dataclasses.replace(base[i], fn="sin"),)) for i in range(len(states)))
    return terms


def _library(nx: int, nu: int, degree: int, sin: bool) -> Any:
    """The pysindy feature library matching :func:`library_terms`."""
    # lazy: heavy (pysindy)
    import pysindy as ps

    poly = ps.PolynomialLibrary(degree=degree, include_bias=True)
    if not sin:
        return poly
    fourier = ps.FourierLibrary(n_frequencies=1, include_sin=True, include_cos=False)
    return ps.GeneralizedLibrary(
        [poly, fourier], inputs_per_library=[list(range(nx + nu)), list(range(nx))]
    )


def library_matrix(data: Dataset, norm: _Normalisation, degree: int, sin: bool) -> FloatArray:
    """Pysindy's library matrix for ``data``: every experiment without its last sample, stacked.

    These are the rows ``DiscreteSINDy.fit`` regresses on (states then inputs, normalised).
    """
    # lazy: heavy (pysindy)
    from pysindy.utils import AxesArray, comprehend_axes

    xs = []
    for e in data.experiments:
        z = np.hstack([norm.states(e.y), norm.inputs(e.u)])[:-1]
        xs.append(AxesArray(z, comprehend_axes(z)))
    lib = _library(norm.nx, norm.nu, degree, sin)
    return np.vstack([np.asarray(t, dtype=float) for t in lib.fit_transform(xs)])


#: Rows per experiment on which the structured terms are checked against pysindy's library.
VERIFY_ROWS = 2000


def _head(e: Experiment, n: int) -> Experiment:
    """The first ``n`` samples of an experiment."""
    return Experiment(t=e.t[:n], u=e.u[:n], y=e.y[:n], name=e.name, extra={}, units=dict(e.units))


def verify_terms(terms: Sequence[Term], theta: Any, dataset: Dataset) -> None:
    """Check that ``terms`` evaluated on the raw data equal pysindy's library matrix.

    ``theta`` is the matrix pysindy regressed on: the rows of every experiment but its last
    sample, experiments stacked in order.

    Raises
    ------
    PluginError
        If the number of columns or any value differs beyond :data:`VERIFY_RTOL`.
    """
    theta = np.asarray(theta, dtype=float)
    ours = np.vstack([term_values(terms, e, dataset)[:-1] for e in dataset.experiments])
    if theta.shape != ours.shape:
        raise PluginError(
            f"sindyc: pysindy's library matrix has shape {theta.shape}, the structured terms give "
            f"{ours.shape}; the installed pysindy builds its library differently."
        )
    tol = VERIFY_RTOL * np.maximum(np.max(np.abs(theta), axis=0), 1.0)
    bad = [j for j in range(len(terms)) if np.max(np.abs(theta[:, j] - ours[:, j])) > tol[j]]
    if bad:
        raise PluginError(
            "sindyc: pysindy's library columns do not match the structured terms:",
            [f"column {j}: term {terms[j].label}" for j in bad[:10]],
        )


def term_values(terms: Sequence[Term], e: Experiment, dataset: Dataset) -> FloatArray:
    """Values of ``terms`` on the raw signals of experiment ``e``, shape ``(n, n_terms)``."""
    ct = CompiledTerms(terms)
    cols = {**dict(zip(dataset.outputs, e.y.T)), **dict(zip(dataset.inputs, e.u.T))}
    values = np.array([cols[name] for name, _ in ct.keys])
    return np.asarray(ct.evaluate(values).T)


# -- normalisation ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Normalisation:
    """Offsets and scales of states then inputs; ``z = (s - offset) * scale``."""

    offset: FloatArray
    scale: FloatArray
    nx: int
    nu: int

    @classmethod
    def of(cls, dataset: Dataset, normalize: bool) -> _Normalisation:
        nx, nu = dataset.ny, dataset.nu
        if not normalize:
            return cls(np.zeros(nx + nu), np.ones(nx + nu), nx, nu)
        data = np.hstack([dataset.y, dataset.u])
        # Six significant digits keep the model file readable; the same numbers are used for
        # the regression and in the terms, so the folding stays exact.
        offset = np.array([_round(v) for v in data.mean(axis=0)])
        scale = np.array([_round(1.0 / s) for s in data.std(axis=0)])
        return cls(offset, scale, nx, nu)

    def states(self, y: FloatArray) -> FloatArray:
        """Normalised states (outputs)."""
        return (y - self.offset[: self.nx]) * self.scale[: self.nx]

    def inputs(self, u: FloatArray) -> FloatArray:
        """Normalised inputs."""
        return (u - self.offset[self.nx :]) * self.scale[self.nx :]

    def fold(self, xi: FloatArray) -> FloatArray:
        """Raw-unit coefficients ``(n_terms, nx)`` from pysindy's normalised ``(nx, n_terms)``.

        ``x = offset + z / scale``, so each state's coefficients are divided by its scale and
        its offset is added to the constant term (the first term).  Works on a batch
        ``(..., nx, n_terms)`` too.
        """
        out = np.swapaxes(xi, -1, -2) / self.scale[: self.nx]
        out[..., 0, :] += self.offset[: self.nx]
        return np.asarray(out)


def _round(v: float) -> float:
    return float(f"{v:.6g}")


# -- sweep scoring --------------------------------------------------------------------------------


def free_run_scores(
    terms: Sequence[Term], coefs: FloatArray, valid: Dataset, norm: _Normalisation
) -> FloatArray:
    """Mean free-run fit (percent) of candidate models on every experiment of ``valid``.

    All candidates (``coefs`` of shape ``(n_candidates, n_terms, nx)``, raw units) and all
    experiments are simulated together, one time step at a time, from the first measured
    sample, exactly as :func:`tendonkit.simulate.simulate` does for one model.  A simulation that
    becomes NaN/inf or leaves :data:`DIVERGENCE_BOUND` standard deviations scores ``-inf``.

    Returns
    -------
    array (n_candidates,)
        Fit over the stacked validation experiments, mean over outputs.
    """
    nc = coefs.shape[0]
    if nc == 0:
        return np.zeros(0)
    nx = norm.nx
    ct = CompiledTerms(terms)
    names = [*valid.outputs, *valid.inputs]
    rows = np.array([names.index(name) for name, _ in ct.keys], dtype=int)
    exps = valid.experiments
    ne, n_max = len(exps), max(e.n_samples for e in exps)
    U = np.empty((n_max, norm.nu, 1, ne))
    for j, e in enumerate(exps):
        U[: e.n_samples, :, 0, j] = e.u
        U[e.n_samples :, :, 0, j] = e.u[-1]
    X = np.empty((n_max, nx, nc, ne))
    X[0] = np.stack([e.y[0] for e in exps], axis=-1)[:, None, :]
    V = np.empty((nx + norm.nu, nc, ne))
    bound = DIVERGENCE_BOUND / norm.scale[:nx, None, None]
    centre = norm.offset[:nx, None, None]
    with np.errstate(all="ignore"):
        for k in range(n_max - 1):
            V[:nx] = X[k]
            V[nx:] = U[k]
            theta = ct.evaluate(V[rows])  # (n_terms, nc, ne)
            x = np.einsum("tce,ctj->jce", theta, coefs)
            x[~(np.abs(x - centre) <= bound)] = np.nan  # also catches NaN/inf
            X[k + 1] = x
    out = np.empty(nc)
    y = np.vstack([e.y for e in exps])
    for c in range(nc):
        sim = np.vstack([X[: e.n_samples, :, c, j] for j, e in enumerate(exps)])
        f = fit(y, sim)
        out[c] = -np.inf if not np.all(np.isfinite(f)) else float(np.mean(f))
    return out


def _best(scores: dict[float, float]) -> float:
    """The largest threshold whose score is within :data:`TIE_TOLERANCE` of the best."""
    top = max(scores.values())
    if not math.isfinite(top):
        return max(scores)
    return max(lam for lam, s in scores.items() if s >= top - TIE_TOLERANCE)


def _require_rows(dataset: Dataset, n_terms: int) -> None:
    require_samples(dataset, 2, "sindyc (one transition per experiment)")
    rows = sum(e.n_samples - 1 for e in dataset.experiments)
    if rows < n_terms:
        raise DataError(
            f"Too few samples for sindyc: {rows} transitions for a library of {n_terms} terms; "
            "use more data, a lower degree or sin=false."
        )


def _is_number(v: object) -> bool:
    ok = isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
    return ok and math.isfinite(float(v))  # type: ignore[arg-type]


@hookimpl
def tendonkit_register_identifiers(registry):  # type: ignore[no-untyped-def]
    """Register the SINDYc identifier."""
    registry.add(SINDYc)
