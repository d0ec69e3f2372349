"""The option objects of :class:`~tendonkit.mpc.LinearMPC` and :class:`~tendonkit.mpc.NonlinearMPC`.

The twenty settings of an MPC design fall into four concerns, grouped as do-mpc and
python-control group them: what the cost weighs (:class:`Weights`), where inputs and outputs
must stay (:class:`Bounds`), how the state and disturbances are estimated (:class:`Estimator`)
and how the QP is solved (:class:`Solver`).  Each is a small frozen dataclass; the controller
checks the values against the model (shapes, signs) and reports every problem at once.

Examples
--------
>>> from tendonkit.mpc import Bounds, Solver, Weights
>>> Bounds(u_min=-1.0, u_max=1.0).u_max
1.0
>>> Weights(R=0.5).slack
1000.0
>>> Solver(name="osqp").fast
True
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from ..errors import OptionError, raise_if

if TYPE_CHECKING:
    from .base import InputTarget, NoiseCovariance

__all__ = ["Bounds", "Estimator", "Solver", "Weights", "resolve_options"]


@dataclass(frozen=True)
class Weights:
    """What the cost weighs.

    Parameters
    ----------
    Q : float or array, optional
        Output tracking weight (scalar, ``(ny,)`` diagonal or ``(ny, ny)``); identity by default.
    R : float or array, optional
        Weight on input moves ``Δu`` (per squared input unit); 0.1 by default.
    Qf : float or array, optional
        Terminal output weight; ``Q`` by default.
    slack : float or (float, float)
        Weights ``(ρ1, ρ2)`` of the linear and quadratic penalty on output-bound slack (a
        scalar ``ρ`` means ``(ρ, ρ)``).
    input_target : InputTarget, optional
        A penalty holding the input directions the outputs leave free.
    """

    Q: ArrayLike | None = None
    R: ArrayLike | None = None
    Qf: ArrayLike | None = None
    slack: float | tuple[float, float] = 1e3
    input_target: InputTarget | None = None


@dataclass(frozen=True)
class Bounds:
    """Where inputs and outputs must stay.

    Parameters
    ----------
    u_min, u_max : float or array (nu,)
        Hard input bounds (the tendon forces, N, by default: 20..190).
    y_min, y_max : float or array (ny,)
        Soft output bounds (slack-penalised), rad by default ±1.
    du_max : float or array (nu,)
        Hard bound on input moves per step (``inf``: none).
    """

    u_min: ArrayLike = 20.0
    u_max: ArrayLike = 190.0
    y_min: ArrayLike = -1.0
    y_max: ArrayLike = 1.0
    du_max: ArrayLike = np.inf


@dataclass(frozen=True)
class Estimator:
    """How the state and the model-plant mismatch are estimated.

    Parameters
    ----------
    disturbance : str
        Integrating disturbance model for offset-free tracking: ``"output"``, ``"input"``
        (:class:`~tendonkit.mpc.LinearMPC` only) or ``"none"``.
    noise : NoiseCovariance, optional
        Noise covariances of the Kalman filter; :class:`NoiseCovariance` defaults otherwise.
    """

    disturbance: str = "output"
    noise: NoiseCovariance | None = None


@dataclass(frozen=True)
class Solver:
    """How the QP is solved.

    Parameters
    ----------
    name : str
        ``"clarabel"`` (default), ``"osqp"`` or a cvxpy solver name.
    fast : bool
        Call the solver directly on the canonicalised QP (no cvxpy per step).
    options : mapping, optional
        Options passed to the solver.
    formulation : str
        ``"auto"``, ``"sparse"`` or ``"condensed"`` (:class:`~tendonkit.mpc.LinearMPC` only).
    failure_hook : callable, optional
        ``hook(step) -> bool`` called when a step fails; True re-raises instead of holding the
        previous input.
    """

    name: str = "clarabel"
    fast: bool = True
    options: Mapping[str, Any] | None = None
    formulation: str = "auto"
    failure_hook: Callable[[int], bool] | None = None


#: The keywords of tendonkit 0.1 and where they live now: keyword -> (group, field).
LEGACY: dict[str, tuple[str, str]] = {
    "Q": ("weights", "Q"),
    "R": ("weights", "R"),
    "Qf": ("weights", "Qf"),
    "slack_weight": ("weights", "slack"),
    "input_target": ("weights", "input_target"),
    "u_min": ("bounds", "u_min"),
    "u_max": ("bounds", "u_max"),
    "y_min": ("bounds", "y_min"),
    "y_max": ("bounds", "y_max"),
    "du_max": ("bounds", "du_max"),
    "disturbance": ("estimator", "disturbance"),
    "noise": ("estimator", "noise"),
    "solver": ("solver", "name"),
    "fast": ("solver", "fast"),
    "solver_options": ("solver", "options"),
    "formulation": ("solver", "formulation"),
    "failure_hook": ("solver", "failure_hook"),
}
_GROUPS: dict[str, type] = {
    "weights": Weights,
    "bounds": Bounds,
    "estimator": Estimator,
    "solver": Solver,
}


def resolve_options(
    owner: str,
    groups: dict[str, Any],
    legacy: dict[str, Any],
    allowed: frozenset[str] = frozenset(LEGACY),
) -> dict[str, Any]:
    """The four option objects, from the given ones and the 0.1 keywords (deprecated).

    Parameters
    ----------
    owner : str
        The controller class (for messages).
    groups : dict
        ``weights``, ``bounds``, ``estimator`` and ``solver`` as given (None: defaults; a string
        ``solver`` is the 0.1 solver name).
    legacy : dict
        Every other keyword given.
    allowed : frozenset of str
        The 0.1 keywords this controller took.

    Raises
    ------
    OptionError
        An unknown keyword, a keyword given both ways, or an option object of the wrong type
        (every problem listed).
    """
    problems: list[str] = []
    groups = dict(groups)
    if isinstance(groups.get("solver"), str):  # 0.1: solver="osqp"
        legacy = {"solver": groups.pop("solver"), **legacy}
        groups["solver"] = None
    for name, cls in _GROUPS.items():
        value = groups.get(name)
        if value is not None and not isinstance(value, cls):
            problems.append(f"{name} must be a {cls.__name__}, found {type(value).__name__}.")
    unknown = sorted(k for k in legacy if k not in allowed)
    if unknown:
        problems.append(
            f"unknown keyword{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
            f"{owner} takes horizon, weights, bounds, estimator and solver."
        )
    changes: dict[str, dict[str, Any]] = {name: {} for name in _GROUPS}
    for key, value in legacy.items():
        if key not in allowed:
            continue
        group, field = LEGACY[key]
        if groups.get(group) is not None:
            problems.append(f"{key} is given both as a keyword and in {group}=.")
        changes[group][field] = value
    raise_if(problems, OptionError, f"Cannot build {owner}:")
    given = [k for k in legacy if k in allowed]
    if given:
        moved = ", ".join(f"{k} -> {LEGACY[k][0]}.{LEGACY[k][1]}" for k in given)
        warnings.warn(
            f"{owner}({', '.join(given)}=...) is the keyword form of tendonkit 0.1; pass option "
            f"objects instead ({moved}). The keywords work until the next release.",
            DeprecationWarning,
            stacklevel=3,
        )
    out: dict[str, Any] = {}
    for name, cls in _GROUPS.items():
        base = groups.get(name) or cls()
        out[name] = replace(base, **changes[name]) if changes[name] else base
    return out


def option_fields(cls: type) -> list[str]:
    """Field names of an option class (for docs and tests)."""
    return [f.name for f in fields(cls)]
