"""The robot's MPC controllers as the co-simulation runs them: settings, tuned defaults, factory.

Kept apart from the co-simulation master (:mod:`tendonkit.robot.cosim`, which re-exports these names)
so that each module stays one concept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import OptionError, raise_if
from ..mpc import (
    Bounds,
    Estimator,
    InputTarget,
    LinearMPC,
    NoiseCovariance,
    NonlinearMPC,
    Solver,
    Weights,
)
from ..mpc.linear import linear_problems
from ..mpc.nonlinear import nonlinear_problems

#: Nominal pretension per tendon (N): the pair sums the controllers hold are twice this.
PRETENSION = 105.0
#: Antagonistic tendon pairs (u1, u3) and (u2, u4): rows select the pair sums.
PAIR_SUMS = np.array([[1.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]])


@dataclass(frozen=True)
class ControllerSettings:
    """Weights and estimator settings of the MPC for the tendon robot (``None``: tuned default).

    Units: ``Q`` per rad² of joint error, ``R`` per N² of input move, ``pair_weight`` per N²
    of pair-sum deviation from ``2·PRETENSION``.  The defaults were tuned in co-simulation on
    the nominal and the paper-like plant (``tests/integration/test_mpc_cosim.py``):
    ``Q = 1e4`` makes 10 mrad of error cost as much as a 1 N move with ``R = 1``, which keeps
    the QP well scaled (the MPC's own default ``R = 0.1`` with ``Q = 1`` is ~10⁵ times slower).

    Parameters
    ----------
    horizon : int
        Prediction horizon N, samples (30 ms each).
    Q, R : float
        Output-error and input-move weights (times identity).
    pair_weight : float
        Weight of the pair-sum input target (0: none).  Two tendons per plane leave the
        common mode free; without the target a model that is wrong along it lets the inputs
        drift, down to slack tendons.
    process, measurement, disturbance : float
        Noise covariances of the state estimator (:class:`tendonkit.mpc.NoiseCovariance`).
    du_max : float
        Largest input move per step, N (inf: none).
    y_bound : float
        Soft joint-angle bounds ±``y_bound``, rad (inf: none).
    solver : {"clarabel", "osqp"}
        QP solver.
    fast : bool
        Direct solver interface (True) or cvxpy ``problem.solve`` (the design path).
    """

    horizon: int | None = None
    Q: float | None = None
    R: float | None = None
    pair_weight: float | None = None
    process: float | None = None
    measurement: float | None = None
    disturbance: float | None = None
    du_max: float | None = None
    y_bound: float | None = None
    solver: str = "clarabel"
    fast: bool = True


_COMMON: dict[str, Any] = {
    "horizon": 20,
    "Q": 1e4,
    "R": 0.3,
    "pair_weight": 1.0,
    "process": 1e-4,
    "disturbance": 1e-5,
    "du_max": np.inf,
    "y_bound": 1.0,
}
#: Tuned defaults per controller kind (see :class:`ControllerSettings`).
DEFAULTS: dict[str, dict[str, Any]] = {
    "linear": {**_COMMON, "measurement": 2.5e-5},
    "nonlinear": {**_COMMON, "measurement": 1e-4},
}


def controller_kind(model: Any) -> str:
    """``"linear"`` or ``"nonlinear"``: which MPC controls ``model``; OptionError if neither.

    Parameters
    ----------
    model : Model
        A tendonkit model with four force inputs and the outputs q1, q2.

    Returns
    -------
    str

    Examples
    --------
    >>> from tendonkit.mpc.examples import tendon_sparse_map, two_mode_model
    >>> controller_kind(two_mode_model()), controller_kind(tendon_sparse_map())
    ('linear', 'nonlinear')
    """

    problems = []
    if len(model.inputs) != 4:
        problems.append(
            f"the model must have the four tendon forces as inputs, found {model.input_names}"
        )
    if sorted(model.output_names) != ["q1", "q2"]:
        problems.append(f"the model's outputs must be q1 and q2, found {model.output_names}")
    kind = "nonlinear" if model.kind == "sparse_map" else "linear"
    problems += nonlinear_problems(model) if kind == "nonlinear" else linear_problems(model)
    raise_if(problems, OptionError, f"Model {model.name!r} cannot be controlled:")
    return kind


def make_controller(
    model: Any,
    settings: ControllerSettings | None = None,
    *,
    failure_hook: Callable[[int], bool] | None = None,
) -> Any:
    """The MPC for ``model``: :class:`~tendonkit.mpc.LinearMPC` or ``NonlinearMPC``.

    Linear models (``state_space``, ``arx`` without terms, delay and lag blocks) get the linear MPC,
    ``sparse_map`` models (SINDYc) the nonlinear one; anything else raises OptionError with
    every reason.  The model's inputs are the commanded forces T_cmd1..T_cmd4, in order.

    Parameters
    ----------
    model : Model
        Four force inputs, outputs q1 and q2.
    settings : ControllerSettings, optional
        Overrides of the tuned defaults.
    failure_hook : callable, optional
        Forces solver failures (tests): ``failure_hook(step) -> bool``.

    Returns
    -------
    LinearMPC or NonlinearMPC

    Examples
    --------
    >>> from tendonkit.mpc.examples import two_mode_model
    >>> ctrl = make_controller(two_mode_model(), ControllerSettings(horizon=10))
    >>> type(ctrl).__name__, ctrl.horizon
    ('LinearMPC', 10)
    """

    kind = controller_kind(model)
    s = settings or ControllerSettings()
    opt = {
        k: (DEFAULTS[kind][k] if getattr(s, k) is None else getattr(s, k)) for k in DEFAULTS[kind]
    }
    q_weight = np.ones(2) * opt["Q"]  # the outputs may be (q2, q1): a scalar weight fits both
    target = None
    if opt["pair_weight"] > 0:
        target = InputTarget(opt["pair_weight"] * PAIR_SUMS.T @ PAIR_SUMS, PRETENSION)
    weights = Weights(Q=q_weight, R=opt["R"], input_target=target)
    bounds = Bounds(y_min=-opt["y_bound"], y_max=opt["y_bound"], du_max=opt["du_max"])
    noise = NoiseCovariance(opt["process"], opt["measurement"], opt["disturbance"])
    estimator = Estimator(noise=noise)
    solver = Solver(name=s.solver, fast=s.fast, failure_hook=failure_hook)
    cls = LinearMPC if kind == "linear" else NonlinearMPC
    return cls(
        model,
        horizon=opt["horizon"],
        weights=weights,
        bounds=bounds,
        estimator=estimator,
        solver=solver,
    )
