"""Frequency responses: a linear model's, and an empirical estimate from measured data.

:func:`model_response` evaluates ``G(z) = C (zI - A)⁻¹ B + D`` on the unit circle for any
linear model (its exact state-space realisation, input delays included; the operating point
does not enter).  :func:`empirical_response` is the H1 spectral estimate ``Ĝ = S_yu S_uu⁻¹``
from Welch-averaged cross spectra (Hann windows, 50 % overlap) — the multivariable form, so
correlated inputs are separated as long as ``S_uu`` is well conditioned; MATLAB's ``spa`` and
``etfe`` are the same family.  Comparing the two on a Bode plot shows where in frequency a
model departs from the data, which a time-domain fit does not.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .dataset import Dataset
from .errors import DataError
from .realize import to_state_space
from .schema import Model

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def model_response(model: Model, freqs: FloatArray) -> ComplexArray:
    """``G(e^{j 2π f dt})`` of a linear model, shape ``(len(freqs), ny, nu)``.

    Raises
    ------
    SchemaError
        If the model is nonlinear (it has no transfer function).
    """
    ss = to_state_space(model)
    A, B, C, D = (np.asarray(m, dtype=float) for m in (ss.A, ss.B, ss.C, ss.D))
    n = A.shape[0]
    z = np.exp(2j * np.pi * np.asarray(freqs, dtype=float) * model.dt)
    out = np.empty((z.size, C.shape[0], B.shape[1]), dtype=complex)
    eye = np.eye(n)
    for i, zi in enumerate(z):
        out[i] = (C @ np.linalg.solve(zi * eye - A, B) if n else 0.0) + D
    return out


def empirical_response(
    data: Dataset, segment: int | None = None
) -> tuple[FloatArray, ComplexArray, FloatArray]:
    """H1 estimate ``S_yu S_uu⁻¹`` from Welch spectra of every experiment.

    Parameters
    ----------
    data : Dataset
        Inputs and outputs; spectra are averaged over experiments (their means removed).
    segment : int, optional
        Welch segment length in samples (default: a quarter of the shortest experiment,
        at most 2048, at least 16): longer segments resolve finer, shorter ones average more.

    Returns
    -------
    freqs : array
        Frequencies in Hz (0 excluded).
    G : array
        ``(len(freqs), ny, nu)`` complex response.
    coherence : array
        ``(len(freqs), ny)``: the multiple coherence of every output with all inputs (1:
        explained linearly by the inputs; low: noise or nonlinearity).
    """
    # lazy: heavy (scipy.signal)
    from scipy.signal import csd

    shortest = min(e.n_samples for e in data.experiments)
    nper = segment or int(min(2048, max(16, shortest // 4)))
    if nper > shortest or nper < 4:
        raise DataError(
            f"The spectral estimate needs segments of 4 to {shortest} samples, found {nper}."
        )
    nu, ny = data.nu, data.ny
    Suu: Any = 0.0
    Syu: Any = 0.0
    Syy: Any = 0.0
    fs = 1.0 / data.dt
    for e in data.experiments:
        u = e.u - e.u.mean(axis=0)
        y = e.y - e.y.mean(axis=0)
        kw = {"fs": fs, "nperseg": nper, "axis": 0}
        f, _ = csd(u[:, 0], u[:, 0], **kw)
        suu = np.empty((f.size, nu, nu), complex)
        syu = np.empty((f.size, ny, nu), complex)
        syy = np.empty((f.size, ny), float)
        for a in range(nu):
            for b in range(nu):  # S_uu[a, b] = E[U_a conj(U_b)]; csd(x, y) = E[conj(X) Y]
                suu[:, a, b] = csd(u[:, b], u[:, a], **kw)[1]
            for j in range(ny):
                syu[:, j, a] = csd(u[:, a], y[:, j], **kw)[1]
        for j in range(ny):
            syy[:, j] = csd(y[:, j], y[:, j], **kw)[1].real
        Suu, Syu, Syy = Suu + suu, Syu + syu, Syy + syy
    keep = f > 0
    f, Suu, Syu, Syy = f[keep], Suu[keep], Syu[keep], Syy[keep]
    G = np.empty((f.size, ny, nu), complex)
    coh = np.empty((f.size, ny))
    for i in range(f.size):
        inv = np.linalg.pinv(Suu[i])
        G[i] = Syu[i] @ inv
        explained = np.einsum("ja,ab,jb->j", Syu[i], inv, Syu[i].conj()).real
        coh[i] = np.clip(explained / np.maximum(Syy[i], 1e-300), 0.0, 1.0)
    return np.asarray(f), G, coh
