"""Preprocessing of measured data: zero-phase low-pass filtering, including the paper's filter.

The paper low-pass filtered the joint angles offline with a "cut-off 0.001 rad per sample"
(30 ms samples).  That is ambiguous (plant.md §11):

- ``"literal"``: 0.001 rad/sample is an angular frequency, f_c = 0.001 / (2π·0.03 s) ≈ 5.3 mHz;
- ``"matlab"``: MATLAB's ``lowpass`` normalised frequency, 0.001·π rad/sample,
  f_c = 0.001 / (2·0.03 s) ≈ 16.7 mHz.

Either removes everything faster than one cycle per 60–190 s — including 4–30 s circles — so
the literal value is suspect; identification works best with 1–2 Hz or no filter.  Both
conventions are offered for reproducing the paper, with a warning in their docstring.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .dataset import Dataset
from .errors import OptionError

PAPER_CUTOFF = 0.001  # "rad per sample"


def paper_cutoff_hz(dt: float, convention: str = "literal") -> float:
    """The paper's cut-off in Hz for sample time ``dt`` under a reading of its unit.

    Examples
    --------
    >>> round(paper_cutoff_hz(0.03, "literal") * 1e3, 2), round(paper_cutoff_hz(0.03, "matlab") * 1e3, 2)
    (5.31, 16.67)
    """
    if convention == "literal":
        return PAPER_CUTOFF / (2 * np.pi * dt)
    if convention == "matlab":
        return PAPER_CUTOFF / (2 * dt)
    raise OptionError(f"convention must be 'literal' or 'matlab', found {convention!r}.")


def lowpass(
    data: Dataset,
    cutoff_hz: float,
    *,
    order: int = 4,
    signals: Sequence[str] | None = None,
) -> Dataset:
    """Zero-phase Butterworth low-pass (forward-backward, second-order sections) of named signals.

    Parameters
    ----------
    data : Dataset
        The data; every experiment is filtered on its own.
    cutoff_hz : float
        Cut-off frequency, below the Nyquist frequency ``1 / (2 dt)``.
    order : int
        Butterworth order of one pass (the zero-phase result has twice the attenuation).
    signals : sequence of str, optional
        Inputs and/or outputs to filter (default: the outputs, as the paper did).

    Returns
    -------
    Dataset
        A new dataset; the input is not modified.
    """
    # lazy: heavy (scipy)
    from scipy.signal import butter, sosfiltfilt

    nyquist = 0.5 / data.dt
    problems = []
    if not (np.isfinite(cutoff_hz) and 0 < cutoff_hz < nyquist):
        problems.append(
            f"cutoff_hz must be in (0, {nyquist:g}) Hz for dt = {data.dt:g} s, found {cutoff_hz!r}."
        )
    if isinstance(order, bool) or not isinstance(order, int) or order < 1:
        problems.append(f"order must be an integer >= 1, found {order!r}.")
    names = list(signals) if signals is not None else list(data.outputs)
    unknown = [n for n in names if n not in (*data.inputs, *data.outputs)]
    if unknown:
        problems.append(
            f"unknown signals {unknown}; inputs {list(data.inputs)}, outputs {list(data.outputs)}."
        )
    short = [e.name for e in data.experiments if e.n_samples <= 6 * order]
    if short:
        problems.append(f"experiments too short to filter: {short}.")
    if problems:
        raise OptionError("Cannot low-pass filter the data:", problems)
    sos = butter(order, cutoff_hz, btype="low", fs=1.0 / data.dt, output="sos")
    exps = []
    for e in data.experiments:
        u, y = e.u.copy(), e.y.copy()
        for n in names:
            if n in data.inputs:
                j = data.inputs.index(n)
                u[:, j] = sosfiltfilt(sos, u[:, j])
            else:
                j = data.outputs.index(n)
                y[:, j] = sosfiltfilt(sos, y[:, j])
        exps.append(dataclasses.replace(e, u=u, y=y))
    return data.with_experiments(exps)


def paper_lowpass(data: Dataset, convention: str = "literal", order: int = 4) -> Dataset:
    """The paper's offline filter of the outputs (see the module docstring: the value is suspect).

    Parameters
    ----------
    data : Dataset
        The data.
    convention : {"literal", "matlab"}
        How to read "0.001 rad per sample".
    order : int
        Butterworth order of one pass.
    """
    return lowpass(data, paper_cutoff_hz(data.dt, convention), order=order)
