"""Output-error refinement: re-estimate an ARX model by its free-run simulation error.

Least squares on the ARX regression minimises the *one-step prediction* error. That is the
maximum-likelihood estimate only when the noise enters as equation error; with measurement
noise on the outputs, or with a model that is only an approximation, the simulation the model
is judged by can be much worse than its one-step predictions. The output-error (OE) estimate
minimises the simulation error itself (Ljung, *System Identification*, 2nd ed., §4.2 and
§7.3; MATLAB's ``oe`` / ``pem`` with a zero noise model): the ARX coefficients start from
least squares and are refined on the normalised free-run errors by
:func:`tendonkit.output_error.refine`, the refinement of any model, with the blocks kept.

What is refined: every coefficient of ``A``, the non-zero entries of ``B`` (orders that
differ per input stay zero), the offset, and the coefficients of the model's terms.  Two
kinds of structure stay fixed: blocks (their parameters were chosen by the caller) and
**clipped-state terms**, ``relu`` of a past output ``j`` at lag ``i`` whose coefficients are
exactly ``±A_i[:, j]`` — the form in which a state clipped inside the recursion is written
(``Σ A_i clip(y[k-i])``, see the ``saturation`` effect).  Those follow ``A`` so that the clip
stays a clip.
"""

from __future__ import annotations

from tendonkit.dataset import Dataset
from tendonkit.errors import OptionError
from tendonkit.output_error import refine
from tendonkit.schema import ARX, Model


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
    if not isinstance(model.representation, ARX):
        raise OptionError(
            f"output-error refinement needs an ARX model, found "
            f"{type(model.representation).__name__}."
        )
    refined = refine(model, data, max_nfev=max_nfev, tol=tol, blocks=False)
    # the caller builds the provenance of the refined model
    return model if refined is model else model.replace(representation=refined.representation)
