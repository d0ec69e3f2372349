"""Residual analysis: where and how a model's simulation is wrong.

Two kinds of residual are analysed, as in MATLAB's ``resid``:

- **free-run residuals** ``y - ŷ_sim``: what the simulation gets wrong, and *where* (near
  velocity reversals, at high |input|, at large |output|, after input changes, at high or low
  common-mode input level);
- **one-step residuals** ``y - ŷ(t|t-1)``: their whiteness (autocorrelation) and their
  cross-correlation with every input at lags −25..25, with 99 % confidence bands
  ``±2.576/√N``; a correlation outside the band at a lag is dynamics the model misses there.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dataset import Dataset
from ..metrics import fit
from ..predict import predict
from ..schema import Model
from ..simulate import aligned, simulate

FloatArray = NDArray[np.float64]

#: Two-sided 99 % normal quantile, for correlation confidence bands.
Z99 = 2.5758293035489


@dataclass(frozen=True)
class Concentration:
    """RMS residual inside a condition relative to outside it (1 = no concentration)."""

    condition: str
    output: str
    ratio: float
    fraction: float  # share of samples inside the condition

    def to_dict(self) -> dict[str, Any]:
        """Plain data."""
        return {
            "condition": self.condition,
            "output": self.output,
            "ratio": self.ratio,
            "fraction": self.fraction,
        }


@dataclass(frozen=True)
class ResidualAnalysis:
    """Residual statistics of one model on one dataset (all experiments concatenated)."""

    outputs: tuple[str, ...]
    inputs: tuple[str, ...]
    residual: FloatArray  # free run, (n, ny)
    one_step: FloatArray  # one-step-ahead, (n, ny)
    fit: dict[str, float]
    concentration: tuple[Concentration, ...]
    lags: FloatArray  # -max_lag..max_lag
    autocorr: FloatArray  # (ny, max_lag+1) of one-step residuals
    crosscorr: FloatArray  # (ny, nu, 2*max_lag+1): corr(e_j[t], u_m[t-lag])
    band: float
    strongest: dict[str, Any] = field(default_factory=dict)

    @property
    def white(self) -> dict[str, bool]:
        """Per output: True when the one-step residual autocorrelation stays inside the band
        (at most 1 % of lags 1..max outside, i.e. what chance allows)."""
        out = {}
        for j, name in enumerate(self.outputs):
            ac = self.autocorr[j, 1:]
            out[name] = bool(np.mean(np.abs(ac) > self.band) <= 0.01 + 1.0 / max(len(ac), 1))
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (no long arrays)."""
        return {
            "fit": self.fit,
            "white": self.white,
            "band_99": self.band,
            "concentration": [c.to_dict() for c in self.concentration],
            "strongest_input_correlation": self.strongest,
        }


def _xcorr(e: FloatArray, u: FloatArray, max_lag: int) -> FloatArray:
    """Normalised cross-correlation r(lag) = corr(e[t], u[t-lag]), lag = -max_lag..max_lag."""
    e = np.ascontiguousarray(e, dtype=float)
    u = np.ascontiguousarray(u, dtype=float)
    e = e - e.mean()
    u = u - u.mean()
    den = np.sqrt(np.sum(e * e) * np.sum(u * u))
    n = len(e)
    out = np.zeros(2 * max_lag + 1)
    if den == 0:
        return out
    # Σ_t e[t] u[t-lag] for every lag at once, by FFT (zero-padded, so no wrap-around).
    size = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.fft.rfft(e, size) * np.conj(np.fft.rfft(u, size)), size)
    lags = np.arange(-max_lag, max_lag + 1)
    out[:] = full[lags % size] / den
    return out


BoolArray = NDArray[np.bool_]


def _reversals(y: FloatArray, width: int) -> BoolArray:
    """Mask of samples within ``width`` samples of a sign change of the (smoothed) velocity."""
    k = max(int(width), 1)
    ys = np.convolve(y, np.ones(k) / k, mode="same")
    v = np.diff(ys, prepend=ys[0])
    s = np.sign(v)
    s[s == 0] = 1
    change = np.flatnonzero(np.diff(s) != 0)
    mask = np.zeros(len(y), dtype=bool)
    for c in change:
        mask[max(c - width, 0) : c + width + 1] = True
    return mask


def _top(x: FloatArray, q: float = 0.9) -> BoolArray:
    return np.asarray(x >= np.quantile(x, q))


def concentration(
    residual: FloatArray,
    u: FloatArray,
    y: FloatArray,
    inputs: tuple[str, ...],
    outputs: tuple[str, ...],
) -> list[Concentration]:
    """Where the residual of every output concentrates (ratio of RMS inside / outside)."""
    out: list[Concentration] = []
    n = residual.shape[0]
    if n < 20:
        return out
    conditions: dict[str, list[BoolArray]] = {}
    # conditions that depend on the output itself are computed per output
    du = np.abs(np.diff(u, axis=0, prepend=u[:1])) if u.shape[1] else np.zeros((n, 0))
    common = u.mean(axis=1) if u.shape[1] else np.zeros(n)
    after_change = np.zeros(n, dtype=bool)
    if u.shape[1]:
        big = np.any(du >= np.quantile(du, 0.9, axis=0)[None, :] + 1e-300, axis=1)
        for shift in range(0, 5):
            after_change[shift:] |= big[: n - shift]
    high_u = (
        np.any(
            np.abs(u - np.median(u, axis=0))
            >= np.quantile(np.abs(u - np.median(u, axis=0)), 0.9, axis=0),
            axis=1,
        )
        if u.shape[1]
        else np.zeros(n, dtype=bool)
    )
    for j, name in enumerate(outputs):
        e = residual[:, j]
        conditions = {
            "near velocity reversals": [_reversals(y[:, j], 3)],
            "high |input|": [high_u],
            "large |output|": [_top(np.abs(y[:, j] - y[:, j].mean()))],
            "after input changes": [after_change],
            "high common-mode input": [_top(common)],
            "low common-mode input": [~_top(common, 0.1)],
        }
        for cond, (mask,) in conditions.items():
            inside, outside = e[mask], e[~mask]
            if inside.size < 5 or outside.size < 5:
                continue
            with np.errstate(over="ignore", invalid="ignore"):  # a diverged run: inf or nan
                r_out = np.sqrt(np.mean(outside**2))
                ratio = float(np.sqrt(np.mean(inside**2)) / r_out) if r_out > 0 else float("inf")
            out.append(Concentration(cond, name, ratio, float(mask.mean())))
    return out


def analyse(
    model: Model, data: Dataset, *, max_lag: int = 25, initial: str = "estimate"
) -> ResidualAnalysis:
    """Residual analysis of ``model`` on ``data`` (see the module docstring).

    Parameters
    ----------
    model : Model
        The model to analyse.
    data : Dataset
        Measured data with the model's inputs and outputs.
    max_lag : int
        Largest lag of the correlation analysis, in samples.
    initial : str
        Initial-state policy of the free-run simulation.

    Returns
    -------
    ResidualAnalysis
    """

    data = aligned(model, data)
    res, one, us, ys = [], [], [], []
    for e in data.experiments:
        sim = simulate(model, e.u, y=e.y, initial=initial)  # type: ignore[arg-type]
        res.append(e.y - sim)
        one.append(e.y - predict(model, e.u, e.y, k=1))
        us.append(e.u)
        ys.append(e.y)
    R, Os, U, Y = (np.vstack(a) for a in (res, one, us, ys))
    R = np.where(np.isfinite(R), R, np.nan)
    f = fit(Y, Y - np.nan_to_num(R, nan=1e300))
    n = Os.shape[0]
    L = min(max_lag, max(n // 4, 1))
    ny, nu = Y.shape[1], U.shape[1]
    auto = np.zeros((ny, L + 1))
    cross = np.zeros((ny, nu, 2 * L + 1))
    strongest: dict[str, Any] = {}
    band = Z99 / np.sqrt(n)
    for j in range(ny):
        full = _xcorr(Os[:, j], Os[:, j], L)
        auto[j] = full[L:]
        best = (0.0, 0, "")
        for m in range(nu):
            cross[j, m] = _xcorr(Os[:, j], U[:, m], L)
            i = int(np.argmax(np.abs(cross[j, m])))
            if abs(cross[j, m, i]) > abs(best[0]):
                best = (float(cross[j, m, i]), i - L, data.inputs[m])
        strongest[data.outputs[j]] = {
            "input": best[2],
            "lag": best[1],
            "correlation": best[0],
            "outside_band": bool(abs(best[0]) > band),
        }
    conc = concentration(np.nan_to_num(R), U, Y, data.inputs, data.outputs)
    return ResidualAnalysis(
        outputs=data.outputs,
        inputs=data.inputs,
        residual=R,
        one_step=Os,
        fit={name: float(v) for name, v in zip(data.outputs, f)},
        concentration=tuple(conc),
        lags=np.arange(-L, L + 1, dtype=float),
        autocorr=auto,
        crosscorr=cross,
        band=float(band),
        strongest=strongest,
    )
