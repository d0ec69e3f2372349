"""Output-error refinement: re-estimate an ARX model by its free-run simulation error.

Least squares on the ARX regression minimises the *one-step prediction* error. That is the
maximum-likelihood estimate only when the noise enters as equation error; with measurement
noise on the outputs, or with a model that is only an approximation, the simulation the model
is judged by can be much worse than its one-step predictions. The output-error (OE) estimate
minimises the simulation error itself (Ljung, *System Identification*, 2nd ed., §4.2 and
§7.3; MATLAB's ``oe`` / ``pem`` with a zero noise model): the ARX coefficients start from
least squares and are refined by :func:`scipy.optimize.least_squares` on the normalised
free-run errors, with forward-difference Jacobians.

What is refined: every coefficient of ``A``, the non-zero entries of ``B`` (orders that
differ per input stay zero), the offset, and the coefficients of the model's terms.  Two
kinds of structure stay fixed: blocks (their parameters were chosen by the caller) and
**clipped-state terms**, ``relu`` of a past output ``j`` at lag ``i`` whose coefficients are
exactly ``±A_i[:, j]`` — the form in which a state clipped inside the recursion is written
(``Σ A_i clip(y[k-i])``, see the ``saturation`` effect).  Those follow ``A`` so that the clip
stays a clip.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from tendonkit.dataset import Dataset
from tendonkit.errors import OptionError
from tendonkit.schema import ARX, Model
from tendonkit.simulate import aligned, simulate

FloatArray = NDArray[np.float64]


def _tied_terms(rep: ARX, outputs: tuple[str, ...]) -> list[tuple[int, int, int, float]]:
    """Clipped-state terms: ``(term index, lag, output index, sign)``."""
    out: list[tuple[int, int, int, float]] = []
    coef = rep.term_coefficients
    if coef is None:
        return out
    for t, term in enumerate(rep.terms):
        if len(term.factors) != 1:
            continue
        f = term.factors[0]
        if f.fn != "relu" or f.signal not in outputs or not 1 <= f.lag <= rep.na:
            continue
        j = outputs.index(f.signal)
        col = rep.A[f.lag - 1][:, j]
        sign = 1.0 if f.scale > 0 else -1.0
        if np.any(col) and np.allclose(coef[t], sign * col, rtol=0, atol=1e-12):
            out.append((t, f.lag, j, sign))
    return out


def _codec(rep: ARX, outputs: tuple[str, ...]) -> tuple[FloatArray, Callable[[FloatArray], ARX]]:
    """The free parameters of ``rep`` as a vector, and the map back to a representation."""
    A = np.array(rep.A) if rep.A else np.zeros((0, len(outputs), len(outputs)))
    B = np.array(rep.B) if rep.B else np.zeros((0, len(outputs), 0))
    b_mask = B != 0
    off = rep.offset
    coef = rep.term_coefficients
    tied = _tied_terms(rep, outputs)
    tied_rows = {t for t, *_ in tied}
    free_rows = [t for t in range(len(rep.terms)) if t not in tied_rows]
    parts = [A.ravel(), B[b_mask]]
    if off is not None:
        parts.append(np.asarray(off, dtype=float).ravel())
    if coef is not None and free_rows:
        parts.append(coef[free_rows].ravel())
    theta0 = np.concatenate(parts) if parts else np.zeros(0)

    def decode(theta: FloatArray) -> ARX:
        pos = A.size
        A_new = theta[:pos].reshape(A.shape)
        B_new = np.zeros_like(B)
        nb = int(b_mask.sum())
        B_new[b_mask] = theta[pos : pos + nb]
        pos += nb
        off_new = None
        if off is not None:
            off_new = theta[pos : pos + off.size].reshape(np.shape(off)).copy()
            pos += off.size
        coef_new = None
        if coef is not None:
            coef_new = coef.copy()
            if free_rows:
                n = len(free_rows) * coef.shape[1]
                coef_new[free_rows] = theta[pos : pos + n].reshape(len(free_rows), -1)
            for t, lag, j, sign in tied:
                coef_new[t] = sign * A_new[lag - 1][:, j]
        return dataclasses.replace(
            rep,
            A=tuple(a.copy() for a in A_new),
            B=tuple(b.copy() for b in B_new),
            offset=off_new,
            term_coefficients=coef_new,
        )

    return theta0, decode


def refine_output_error(
    model: Model, data: Dataset, *, max_nfev: int = 300, tol: float = 1e-6
) -> Model:
    """Re-estimate an ARX ``model`` on ``data`` by minimising its free-run simulation error.

    Parameters
    ----------
    model : Model
        An ARX model (with or without terms and blocks), typically the least-squares estimate.
    data : Dataset
        Data with the model's inputs and outputs.
    max_nfev : int
        Cap on the optimiser's iterations (each costs one simulation per parameter for the
        forward-difference Jacobian; a linear ARX simulates in microseconds per sample, a model
        with terms sample by sample, so a bilinear ARX(3, 3) on 1,000 samples takes seconds).
    tol : float
        Relative tolerance on the cost and on the step (``ftol`` and ``xtol`` of
        :func:`scipy.optimize.least_squares`).

    Returns
    -------
    Model
        The refined model, or ``model`` itself when the refinement does not lower the
        simulation error (the optimiser starts from it, so it never does worse).

    Raises
    ------
    OptionError
        If the model is not ARX.
    """
    # lazy: heavy (scipy)
    from scipy.optimize import least_squares

    rep = model.representation
    if not isinstance(rep, ARX):
        raise OptionError(
            f"output-error refinement needs an ARX model, found {type(rep).__name__}."
        )
    data = aligned(model, data)
    theta0, decode = _codec(rep, model.output_names)
    if theta0.size == 0:
        return model
    scale = np.std(data.y, axis=0)
    scale[scale == 0] = 1.0

    def residuals(theta: FloatArray) -> FloatArray:
        m = model.replace(representation=decode(theta))
        errs = []
        with np.errstate(all="ignore"):
            for e in data.experiments:
                sim = simulate(m, e.u, y=e.y, initial="estimate")
                errs.append(((e.y - sim) / scale).ravel())
        # a diverged simulation is not finite, which makes the optimiser shorten its step
        return np.concatenate(errs)

    r0 = residuals(theta0)
    if not np.all(np.isfinite(r0)):
        return model
    cost0 = float(r0 @ r0)
    with np.errstate(all="ignore"):  # trial steps may diverge; the optimiser steps back
        sol = least_squares(residuals, theta0, x_scale="jac", ftol=tol, xtol=tol, max_nfev=max_nfev)
    if not np.all(np.isfinite(sol.fun)) or float(sol.fun @ sol.fun) >= cost0:
        return model
    return model.replace(representation=decode(sol.x))
