"""An example tendonkit identifier plugin: FIR models by least squares.

``y[k] = sum_{j=0}^{n-1} B_j u[k - delay - j]`` — an ARX model with no output lags, so the
model is returned in the schema's ``arx`` representation and every tendonkit consumer
(simulate, compare, diagnose, export, MPC) works on it with no change.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from tendonkit import hookimpl
from tendonkit.errors import OptionError
from tendonkit.identification import build_model, require_samples
from tendonkit.schema import ARX


@dataclass(frozen=True, kw_only=True)
class FIR:
    """Options of the FIR identifier.

    Parameters
    ----------
    n : int
        Number of impulse-response coefficients per input (>= 1).
    delay : int
        Input delay in samples (>= 0).
    """

    name: ClassVar[str] = "fir"
    description: ClassVar[str] = "Finite impulse response by least squares (example plugin)."

    n: int = 60
    delay: int = 1

    def __post_init__(self) -> None:
        problems = []
        if self.n < 1:
            problems.append(f"n must be >= 1, found {self.n}.")
        if self.delay < 0:
            problems.append(f"delay must be >= 0, found {self.delay}.")
        if problems:
            raise OptionError("Invalid options for fir:", problems)

    def identify(self, dataset):
        """Estimate the impulse response from ``dataset``."""
        lag = self.delay + self.n - 1
        require_samples(dataset, lag + 1 + self.n * dataset.nu, "fir")
        rows, targets = [], []
        for e in dataset.experiments:
            cols = [e.u[lag - self.delay - j : e.n_samples - self.delay - j] for j in range(self.n)]
            rows.append(np.hstack(cols))
            targets.append(e.y[lag:])
        theta, *_ = np.linalg.lstsq(np.vstack(rows), np.vstack(targets), rcond=None)
        nu = dataset.nu
        B = tuple(theta[j * nu : (j + 1) * nu].T.copy() for j in range(self.n))
        return build_model(self, dataset, ARX(A=(), B=B, nk=(self.delay,) * nu))


@hookimpl
def tendonkit_register_identifiers(registry):
    """Register the FIR identifier."""
    registry.add(FIR)
