"""ARX: multi-input multi-output AutoRegressive model with eXogenous inputs, by least squares.

``y[k] + A1 y[k-1] + ... + A_na y[k-na] = B1 u[k-nk] + ... + B_nb u[k-nk-nb+1] (+ offset)``

Every output regresses on the past of *every* output (full ``ny×ny`` matrices, so outputs can
couple) and of every input.  Orders and delays may differ per input.  The regressors are built
per experiment and stacked (never the signals), columns are scaled to unit norm, and the least-
squares problem is solved by a QR-based solver (LAPACK ``gelsy``), which is stable when forces
in newtons and angles in radians share one regression.  The paper's orders are the defaults:
``na = nb = 8``, ``nk = 1``.

``bilinear=True`` adds the products ``u_m[k-nk_m] · y_j[k-1]`` of every input with every
output as regressors (a *bilinear* ARX, the discrete form of ``ẋ = A x + B u + Σ_m u_m N_m x``,
Mohler 1973).  It is the smallest model class in which an input changes the system's gain or
stiffness: the tendon robot's joints stiffen with the sum of the tensions, so
``q ≈ ρ ΔT / K(ΣT)``, which no linear model represents (nominal plant: ARX(3, 3, 1) 85 %,
bilinear 95 % validation fit).  The products are stored as ordinary model terms, so the model
simulates, compares and exports like any other ARX.

``criterion="simulation"`` estimates the same model by its free-run simulation error (output
error): least squares, then two steps of instrumental variables, then
:func:`tendonkit.plugins._output_error.refine_output_error` from the better start.  Least squares is biased
when the outputs are measured with noise; on a lightly damped oscillator with 5 % output noise
it simulates at 1 % fit, the output-error estimate at the noise ceiling (95 %), as SIPPY's OE.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset
from tendonkit.errors import DataError, OptionError
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
from tendonkit.plugins import _arx_structure
from tendonkit.plugins._arx_structure import as_tuple
from tendonkit.plugins._output_error import refine_output_error
from tendonkit.regression import scaled_lstsq, term_columns
from tendonkit.schema import ARX as ARXRep
from tendonkit.schema import Model
from tendonkit.simulate import simulate
from tendonkit.terms import Factor, Term

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, kw_only=True)
class ARX:
    """Options of the ARX identifier.

    Parameters
    ----------
    na : int or "auto"
        Number of past outputs (>= 0).
    nb : int, tuple of int or "auto"
        Number of past values per input (>= 0); one value for all inputs or one per input.
    nk : int, tuple of int or "auto"
        Input delay in samples (>= 0); one value for all inputs or one per input.
        ``"auto"`` for any of the three selects it on the training data
        (:mod:`tendonkit.plugins._arx_structure`: delays per input as MATLAB's ``delayest``,
        orders by blocked cross-validation of the simulation error); the candidates are
        stored in the provenance.
    max_order : int
        Largest ``na`` and ``nb`` the automatic choice tries.
    equal_orders : bool
        The automatic choice tries ``na = nb`` only (``max_order`` candidates instead of
        ``(max_order + 1) · max_order``): what ``diagnose`` uses to choose its baseline.
    max_delay : int or "auto"
        Largest delay the automatic choice tries; ``"auto"`` (default): as far as the data
        support, a twentieth of the shortest experiment, at least 10 and at most 160 samples
        (:func:`tendonkit.plugins._arx_structure.delay_range`).
    offset : bool or "auto"
        Also estimate a constant offset per output; ``"auto"`` chooses with and without by the
        same cross-validation as the orders.
    ridge : float
        Tikhonov regularisation weight on the (scaled) parameters; 0 for plain least squares.
    bilinear : bool
        Also regress on the products ``u_m[k-nk_m] · y_j[k-1]`` of every input with every
        output (``u_m[k-1]`` when ``nk_m = 0``): input-dependent gain and stiffness.
    jobs : int
        Worker processes scoring the automatic choice's candidates (:mod:`tendonkit.parallel`);
        1 (default) scores them here, which is faster below about a hundred thousand samples
        (benchmarks/README.md, "Sweeps").  The choice does not depend on it.
    criterion : str
        ``"equation"`` (default): least squares on the one-step prediction error.
        ``"simulation"``: start there and refine every coefficient by the free-run simulation
        error (the output-error estimate, as MATLAB's ``oe``;
        :func:`tendonkit.plugins._output_error.refine_output_error`). Slower; better when the outputs are
        measured with noise or the model is judged in simulation.

    Examples
    --------
    >>> ARX(na=2, nb=(2, 1), nk=1).na
    2
    """

    name: ClassVar[str] = "arx"
    description: ClassVar[str] = (
        "MIMO ARX by least squares (QR solver, scaled regressors), or by output error "
        "(criterion='simulation'); orders per input; paper: 8, 8, 1."
    )

    na: int | Literal["auto"] = 8
    nb: int | tuple[int, ...] | Literal["auto"] = 8
    nk: int | tuple[int, ...] | Literal["auto"] = 1
    max_order: int = 10
    equal_orders: bool = False
    max_delay: int | Literal["auto"] = "auto"
    offset: bool | Literal["auto"] = False
    ridge: float = 0.0
    bilinear: bool = False
    criterion: str = "equation"
    jobs: int = 1

    def __post_init__(self) -> None:
        p = []
        if not is_int(self.jobs) or self.jobs < 1:
            p.append(f"jobs must be an integer >= 1, found {self.jobs!r}.")
        if self.na != "auto" and (not is_int(self.na) or self.na < 0):
            p.append(f"na must be an integer >= 0 or 'auto', found {self.na!r}.")
        for key in ("nb", "nk"):
            val = getattr(self, key)
            if val == "auto":
                continue
            vals = val if isinstance(val, tuple) else (val,)
            if not vals or not all(is_int(v) and v >= 0 for v in vals):
                p.append(
                    f"{key} must be an integer >= 0, a tuple of them or 'auto', found {val!r}."
                )
        for key in ("max_order", "max_delay"):
            val = getattr(self, key)
            if key == "max_delay" and val == "auto":
                continue
            if not is_int(val) or val < (1 if key == "max_order" else 0):
                p.append(f"{key} must be an integer >= {int(key == 'max_order')}, found {val!r}.")
        if not isinstance(self.ridge, int | float) or not np.isfinite(self.ridge) or self.ridge < 0:
            p.append(f"ridge must be a number >= 0, found {self.ridge!r}.")
        if not isinstance(self.equal_orders, bool):
            p.append(f"equal_orders must be true or false, found {self.equal_orders!r}.")
        if not (isinstance(self.offset, bool) or self.offset == "auto"):
            p.append(f"offset must be true, false or 'auto', found {self.offset!r}.")
        if not isinstance(self.bilinear, bool):
            p.append(f"bilinear must be true or false, found {self.bilinear!r}.")
        if self.criterion not in ("equation", "simulation"):
            p.append(f"criterion must be 'equation' or 'simulation', found {self.criterion!r}.")
        if not p and self.bilinear and self.na == 0:  # ("auto" is never 0)
            p.append("bilinear needs na >= 1: the products read y[k-1].")
        if not p and self.na == 0 and self.nb != "auto" and max(as_tuple(self.nb, 1)) == 0:
            p.append("na and nb are both zero: the model would have no parameters.")
        if p:
            raise OptionError("Invalid options for arx:", p)

    @property
    def n_a(self) -> int:
        """``na`` as given (not ``"auto"``)."""
        assert self.na != "auto", "resolve 'auto' first"
        return self.na

    @property
    def automatic(self) -> bool:
        """Whether any of ``na``, ``nb``, ``nk`` is chosen from the data."""
        return "auto" in (self.na, self.nb, self.nk, self.offset)

    def orders(self, nu: int) -> tuple[list[int], list[int]]:
        """Per-input ``nb`` and ``nk`` lists for ``nu`` inputs (given, not ``"auto"``)."""
        assert self.nb != "auto" and self.nk != "auto", "resolve 'auto' first"
        nb, nk = as_tuple(self.nb, nu), as_tuple(self.nk, nu)
        if len(nb) != nu or len(nk) != nu:
            raise OptionError(
                f"arx: nb and nk must give one value or one per input ({nu}); found nb={self.nb!r}, "
                f"nk={self.nk!r}."
            )
        return list(nb), list(nk)

    def identify(self, dataset: Dataset) -> Model:
        """Estimate the ARX model from ``dataset`` (inputs and outputs as selected there)."""
        if self.automatic:
            return self._identify_automatic(dataset)
        nu, ny = dataset.nu, dataset.ny
        nb, nk = self.orders(nu)
        lag = max([self.n_a, *[k + b - 1 for k, b in zip(nk, nb)], 0])
        if self.bilinear:
            lag = max([lag, *[max(k, 1) for k in nk]])
        n_par = (
            self.n_a * ny + sum(nb) + int(self.offset is True) + (nu * ny if self.bilinear else 0)
        )
        require_samples(dataset, lag + 1, f"arx(na={self.n_a}, nb={self.nb}, nk={self.nk})")
        rows = sum(e.n_samples - lag for e in dataset.experiments)
        if rows < n_par:
            raise DataError(
                f"Too few samples for arx: {rows} regression rows for {n_par} parameters per output."
            )
        with one_blas_thread():
            if self.criterion == "equation":
                return self._fit(dataset, nb, nk, lag)

            with without_training_fit():
                start = self._output_error_start(dataset, nb, nk, lag)
            refined = refine_output_error(start, dataset)
            return build_model(self, dataset, refined.representation)

    def _identify_automatic(self, dataset: Dataset) -> Model:
        with one_blas_thread():
            na, nb, nk, offset, record = _arx_structure.select(self, dataset)
        chosen = dataclasses.replace(self, na=na, nb=nb, nk=nk, offset=offset)
        model = chosen.identify(dataset)
        prov = model.provenance
        note = f"structure selected on the training data: na={na}, nb={list(nb)}, nk={list(nk)}"
        if self.offset == "auto":
            note += f", offset={offset}"
        return model.replace(
            provenance=dataclasses.replace(
                prov,
                options=options_dict(self),
                notes="; ".join(x for x in (prov.notes, note) if x),
                details={
                    **prov.details,
                    **record,
                    "selected": {"na": na, "nb": list(nb), "nk": list(nk), "offset": offset},
                },
            )
        )

    def _regression(
        self, dataset: Dataset, nb: list[int], nk: list[int], lag: int
    ) -> tuple[FloatArray, FloatArray, tuple[Term, ...]]:
        Phi = np.vstack(
            [
                _regressors(e.u, e.y, self.n_a, nb, nk, lag, self.offset is True)
                for e in dataset.experiments
            ]
        )
        Y = np.vstack([e.y[lag:] for e in dataset.experiments])
        terms = bilinear_terms(dataset, nk) if self.bilinear else ()
        if terms:
            Phi = np.hstack(
                [
                    Phi,
                    np.vstack([term_columns(terms, e, dataset)[lag:] for e in dataset.experiments]),
                ]
            )
        return Phi, Y, terms

    def _model(
        self,
        dataset: Dataset,
        theta: FloatArray,
        nb: list[int],
        nk: list[int],
        terms: tuple[Term, ...],
    ) -> Model:
        nu, ny = dataset.nu, dataset.ny
        n_lin = theta.shape[0] - len(terms)
        rep = _to_representation(theta[:n_lin], self.n_a, nb, nk, ny, nu, self.offset is True)
        if terms:
            rep = dataclasses.replace(rep, terms=terms, term_coefficients=theta[n_lin:].copy())
        return build_model(self, dataset, rep)

    def _fit(self, dataset: Dataset, nb: list[int], nk: list[int], lag: int) -> Model:
        Phi, Y, terms = self._regression(dataset, nb, nk, lag)
        return self._model(dataset, _solve(Phi, Y, self.ridge), nb, nk, terms)

    def _output_error_start(
        self, dataset: Dataset, nb: list[int], nk: list[int], lag: int
    ) -> Model:
        """The best start for the output-error refinement: least squares or instrumental variables.

        Least squares is biased by output noise, sometimes so badly that the refinement ends
        in a poor local minimum.  Instrumental variables (Söderström & Stoica, *System
        Identification*, ch. 8) replace the measured outputs in the regressors' instruments by
        a model's noise-free simulation, which makes the estimate consistent for any
        instruments correlated with the regressors: first the least-squares model's
        simulation, then the first IV model's (two steps of the iterative IV). The start with
        the smallest simulation error on the training data is returned.
        """

        def mean_fit(m: Model, data: Dataset) -> float:
            f = np.mean(list(training_fit(m, data).values()))
            return float(f) if np.isfinite(f) else -np.inf

        Phi, Y, terms = self._regression(dataset, nb, nk, lag)
        model = self._model(dataset, _solve(Phi, Y, self.ridge), nb, nk, terms)
        best, best_fit = model, mean_fit(model, dataset)
        scale = np.linalg.norm(Phi, axis=0)
        scale[scale == 0] = 1.0
        for _ in range(2):
            with np.errstate(all="ignore"):
                sims = [
                    simulate(model, e.u, y=e.y, initial="estimate") for e in dataset.experiments
                ]
            if not all(np.all(np.isfinite(x)) for x in sims):
                break
            simulated = dataset.with_experiments(
                [dataclasses.replace(e, y=x) for e, x in zip(dataset.experiments, sims)]
            )
            Z, _, _ = self._regression(simulated, nb, nk, lag)
            try:
                theta = (
                    np.linalg.solve((Z / scale).T @ (Phi / scale), (Z / scale).T @ Y)
                    / scale[:, None]
                )
            except np.linalg.LinAlgError:
                break
            model = self._model(dataset, theta, nb, nk, terms)
            f = mean_fit(model, dataset)
            if f > best_fit:
                best, best_fit = model, f
        return best


def bilinear_terms(dataset: Dataset, nk: list[int]) -> tuple[Term, ...]:
    """The products ``u_m[k - max(nk_m, 1)] · y_j[k-1]`` of every input with every output."""
    return tuple(
        Term((Factor(u, lag=max(k, 1)), Factor(y, lag=1)))
        for u, k in zip(dataset.inputs, nk)
        for y in dataset.outputs
    )


def _regressors(
    u: FloatArray, y: FloatArray, na: int, nb: list[int], nk: list[int], lag: int, offset: bool
) -> FloatArray:
    """Rows ``k = lag..n-1`` of ``[-y[k-1] .. -y[k-na], u_m[k-nk_m] .. u_m[k-nk_m-nb_m+1], 1]``."""
    n = y.shape[0]
    cols = []
    for i in range(1, na + 1):
        cols.append(-y[lag - i : n - i])
    for m, (b, k) in enumerate(zip(nb, nk)):
        for j in range(b):
            d = k + j
            cols.append(u[lag - d : n - d, m : m + 1])
    if offset:
        cols.append(np.ones((n - lag, 1)))
    return np.hstack(cols)


def _solve(Phi: FloatArray, Y: FloatArray, ridge: float) -> FloatArray:
    """Scaled, QR-reduced least squares (:func:`tendonkit.diagnose.extend.scaled_lstsq`)."""

    return scaled_lstsq(Phi, Y, ridge)


def _to_representation(
    theta: FloatArray, na: int, nb: list[int], nk: list[int], ny: int, nu: int, offset: bool
) -> ARXRep:
    A = [theta[i * ny : (i + 1) * ny].T.copy() for i in range(na)]
    nbmax = max(nb) if nb else 0
    B = [np.zeros((ny, nu)) for _ in range(nbmax)]
    pos = na * ny
    for m, b in enumerate(nb):
        for j in range(b):
            B[j][:, m] = theta[pos]
            pos += 1
    off = theta[pos].copy() if offset else None
    return ARXRep(A=tuple(A), B=tuple(B), nk=tuple(nk), offset=off)


@hookimpl
def tendonkit_register_identifiers(registry):  # type: ignore[no-untyped-def]
    """Register the ARX identifier."""
    registry.add(ARX)
