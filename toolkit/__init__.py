"""tendonkit: data-driven dynamic models of a tendon-actuated continuum robot.

Identify models from measured data (N4SID, ARX, SINDYc and any plugin), simulate and compare
them, find what they get wrong and why, export them as FMUs and design MPC controllers that
are checked in co-simulation against a physics plant FMU.
"""

from __future__ import annotations

import warnings

from . import _compat
from .dataset import Dataset, Experiment, dependent_inputs, validation_problems
from .errors import (
    DataError,
    FMUError,
    OptionError,
    OutputError,
    PluginError,
    SchemaError,
    SimulationError,
    TendonkitError,
    TendonkitWarning,
    raise_if,
)
from .hookspecs import hookimpl
from .identification import poor_fit_warning
from .manager import effects, identifiers
from .metrics import fit, fit_table
from .mpc import (
    Bounds,
    Estimator,
    InputTarget,
    LinearMPC,
    NoiseCovariance,
    NonlinearMPC,
    Solver,
    StepResult,
    Weights,
)
from .predict import predict
from .schema import ARX, Block, Model, Provenance, Signal, SparseMap, StateSpace
from .simulate import simulate, simulate_dataset
from .terms import Factor, Term

__version__ = "0.2.0"

_compat.install()  # the old module paths of 0.1, for one release

__all__ = [
    "ARX",
    "Block",
    "Bounds",
    "DataError",
    "Dataset",
    "Estimator",
    "Experiment",
    "FMUError",
    "Factor",
    "InputTarget",
    "LinearMPC",
    "Model",
    "NoiseCovariance",
    "NonlinearMPC",
    "OptionError",
    "OutputError",
    "PluginError",
    "Provenance",
    "SchemaError",
    "Signal",
    "SimulationError",
    "Solver",
    "SparseMap",
    "StateSpace",
    "StepResult",
    "TendonkitError",
    "TendonkitWarning",
    "Term",
    "Weights",
    "__version__",
    "effects",
    "fit",
    "fit_table",
    "hookimpl",
    "identifiers",
    "identify",
    "predict",
    "simulate",
    "simulate_dataset",
]


def identify(dataset: Dataset, method: str = "arx", **options: object) -> Model:
    """Identify a model with a registered method.

    Parameters
    ----------
    dataset : Dataset
        Training data.
    method : str
        Registry name (``n4sid``, ``arx``, ``sindyc`` or a plugin's).
    **options
        Options of the method (see ``tendonkit plugins``).

    Examples
    --------
    >>> import numpy as np, tendonkit as tk
    >>> rng = np.random.default_rng(0)
    >>> u = rng.normal(size=(500, 1)); y = np.zeros((500, 1))
    >>> for k in range(1, 500): y[k] = 0.8 * y[k - 1] + 0.5 * u[k - 1]
    >>> m = tk.identify(tk.Dataset.from_arrays(u, y, dt=0.1), "arx", na=1, nb=1)
    >>> round(float(m.representation.A[0][0, 0]), 6)
    -0.8
    """
    entry = identifiers().get(method)
    # the same checks as the CLI's reading of a file: a NaN or a constant column is reported,
    # not turned into a model of zeros or a numerical library's error
    raise_if(
        validation_problems(dataset), DataError, f"identify ({method}) cannot run on these data:"
    )
    model = entry.create(**options).identify(dataset)
    for why in (dependent_inputs(dataset), poor_fit_warning(model)):
        if why:
            warnings.warn(why[0].upper() + why[1:], TendonkitWarning, stacklevel=2)
    return model
