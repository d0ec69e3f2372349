"""Model predictive control of tendonkit models, designed in cvxpy.

Two controllers share one interface and one tracking problem (:mod:`tendonkit.mpc.qp`):

- :class:`LinearMPC` for every linear model (``state_space``, ``arx``, input delays and lags): the
  exact realisation, reduced when it is not minimal, a steady-state Kalman predictor and
  integrating disturbances for offset-free tracking;
- :class:`NonlinearMPC` for ``sparse_map`` models (SINDYc): successive linearisation along
  the shifted previous plan with closed-form Jacobians of the structured terms, one QP per
  step (real-time iteration), an extended Kalman filter with an output disturbance.

The cost over the horizon ``N`` is ``Σ_{k=1}^{N-1} |y_k - r_k|²_Q + |y_N - r_N|²_Qf +
Σ_{k=0}^{N-1} |Δu_k|²_R`` (no penalty on ``u`` itself unless an :class:`InputTarget` is
given), with hard input bounds (and optional move limits ``du_max``) and soft output
bounds (slack variables with a linear and a quadratic penalty, so the problem is always
feasible).  The predicted output ``y_k`` is sampled while ``u_{k-1}`` is applied (a
feed-through ``D`` acts with the previous input).  Each step the controller holds the last
input if the solver fails, and clips its input to the bounds.

The settings come as four option objects (:mod:`tendonkit.mpc.options`): :class:`Weights`,
:class:`Bounds`, :class:`Estimator` and :class:`Solver`.

The problem is built once with cvxpy parameters (DPP).  ``Solver(fast=False)`` re-solves it with
``problem.solve``; ``Solver(fast=True)`` (default) feeds cvxpy's parameter-affine problem data directly
to a persistent Clarabel or OSQP solver; both give the same inputs.

Examples
--------
>>> import numpy as np
>>> from tendonkit.testsystems import random_state_space
>>> plant = random_state_space(4, 2, 2, seed=1)
>>> bounds = Bounds(u_min=-5, u_max=5, y_min=-10, y_max=10)
>>> mpc = LinearMPC(plant, horizon=10, bounds=bounds)
>>> mpc.reset(np.zeros(2), np.zeros(2))
>>> res = mpc.step(np.zeros(2), np.array([[0.1, -0.1]]))
>>> res.u.shape, bool(np.all(np.abs(res.u) <= 5)), res.fallback
((2,), True, False)
"""

from __future__ import annotations

from .base import InputTarget, NoiseCovariance, StepResult
from .linear import LinearMPC
from .nonlinear import NonlinearMPC
from .options import Bounds, Estimator, Solver, Weights

__all__ = [
    "Bounds",
    "Estimator",
    "InputTarget",
    "LinearMPC",
    "NoiseCovariance",
    "NonlinearMPC",
    "Solver",
    "StepResult",
    "Weights",
]
