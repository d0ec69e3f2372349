"""Goodness-of-fit measures as in the paper (normalised root-mean-square fit, percent)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import DataError

FloatArray = NDArray[np.float64]


def fit(y: FloatArray, y_hat: FloatArray) -> FloatArray:
    """Normalised fit per output: ``100 (1 - ||y - ŷ|| / ||y - mean(y)||)``.

    100 is a perfect match, 0 is as good as the mean, and it is negative (unbounded) when the
    model is worse than the mean.  A simulation that diverged (NaN) scores ``-inf``.

    Parameters
    ----------
    y, y_hat : array (n,) or (n, ny)
        Measured and simulated outputs.

    Returns
    -------
    array (ny,)
        Fit in percent per output.

    Examples
    --------
    >>> import numpy as np
    >>> fit(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 2.0])).tolist()
    [100.0]
    """
    y = np.asarray(y, dtype=float)
    y_hat = np.asarray(y_hat, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    if y_hat.ndim == 1:
        y_hat = y_hat[:, None]
    if y.shape != y_hat.shape:
        raise DataError(f"fit needs equal shapes; found {y.shape} and {y_hat.shape}.")
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        den = np.linalg.norm(y - y.mean(axis=0), axis=0)
        num = np.linalg.norm(y - y_hat, axis=0)
        out = 100.0 * (1.0 - num / den)
    out[~np.isfinite(num)] = -np.inf
    out[den == 0] = np.where(num[den == 0] == 0, 100.0, -np.inf)
    return out


@dataclass(frozen=True)
class FitRow:
    """One model's fit per output and the mean over outputs."""

    model: str
    method: str
    per_output: dict[str, float]

    @property
    def mean(self) -> float:
        """Mean fit over outputs (the paper's single number)."""
        vals = list(self.per_output.values())
        return float(np.mean(vals)) if vals else float("nan")


def fit_table(rows: Sequence[FitRow]) -> str:
    """Plain-text table of fits (the paper's Table I layout)."""
    if not rows:
        return "(no models)"
    outputs = list(rows[0].per_output)
    head = ["model", "method", *[f"fit {o} [%]" for o in outputs], "mean [%]"]
    body = [
        [
            r.model,
            r.method,
            *[_fmt(r.per_output.get(o, float("nan"))) for o in outputs],
            _fmt(r.mean),
        ]
        for r in rows
    ]
    widths = [max(len(str(x)) for x in col) for col in zip(head, *body)]
    lines = ["  ".join(str(x).ljust(w) for x, w in zip(head, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(x).ljust(w) for x, w in zip(row, widths)) for row in body]
    return "\n".join(lines)


def _fmt(v: float) -> str:
    return "diverged" if not np.isfinite(v) else f"{v:.2f}"
