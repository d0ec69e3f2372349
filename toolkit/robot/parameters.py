"""Geometry, mass and stiffness parameters of the rolling-joint snake robot.

This module is the one place that holds the robot's numbers (plant spec §6) and the
contact-radius calibration that makes the paper's constant joint-angle ratios come out of the
physics (spec §8).  Everything else — kinematics, the plant, the kinematic controller, MPC —
takes a :class:`RobotParameters` object and never hard-codes a dimension.

Conventions (spec §1): joints 1, 3, 5 are pan joints (bend in the base x–z plane, driven by the
antagonistic tendon pair T1/T3), joints 2, 4, 6 are tilt joints (y–z plane, pair T2/T4).  Arrays
indexed by joint have length 6 in joint order; arrays indexed by tendon and joint have shape
``(4, 6)``.  All lengths are in metres, masses in kg, tensions in N, angles in rad.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from functools import cached_property
from typing import Any

import numpy as np

from ..errors import OptionError, raise_if

__all__ = [
    "N_JOINTS",
    "N_TENDONS",
    "PAN_JOINTS",
    "PAPER_RATIOS",
    "TILT_JOINTS",
    "RobotParameters",
]

#: Number of rolling joints.
N_JOINTS = 6
#: Number of tendons.
N_TENDONS = 4
#: Zero-based indices of the pan joints (q1, q3, q5), driven by T1 (+) and T3 (−).
PAN_JOINTS = (0, 2, 4)
#: Zero-based indices of the tilt joints (q2, q4, q6), driven by T2 (+) and T4 (−).
TILT_JOINTS = (1, 3, 5)

#: The paper's constant joint-angle ratios, per joint: each joint's angle divided by the angle of
#: the first joint of its plane (q1 for pan joints, q2 for tilt joints).  In joint order:
#: ``(1, 1, q3/q1, q4/q2, q5/q1, q6/q2) = (1, 1, 0.6493, 0.6442, 0.2053, 0.2291)``.
PAPER_RATIOS: tuple[float, float, float, float, float, float] = (
    1.0,
    1.0,
    0.6493,
    0.6442,
    0.2053,
    0.2291,
)

# Tendon angles phi_k (T1 at +x, T2 at +y, T3 at -x, T4 at -y).
_TENDON_ANGLES = np.deg2rad([0.0, 90.0, 180.0, 270.0])

# Flat names of the ratio entries that can be changed (entries 1 and 2 are 1 by definition).
_RATIO_NAMES = ("ratio_3", "ratio_4", "ratio_5", "ratio_6")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class RobotParameters:
    """Geometry, inertia and stiffness of the robot, with the derived calibrated quantities.

    The contact radii ``R`` are not parameters: they are calibrated from ``ratios``,
    ``R_base`` and ``q_cal`` (spec §8) so that, in a frictionless static equilibrium with the
    tension difference that bends joint 1 to ``q_cal`` at ``P_nom``, joint i bends to
    ``ratios[i] * q_cal``.  Derived quantities are computed once per object and returned as
    read-only arrays.

    Parameters
    ----------
    link_pitch : float
        Distance from a link's bottom contact point to its top contact point, m.
    tool_offset : float
        End-effector point beyond the top contact point of link 6, m.
    rho : float
        Tendon routing radius, m.
    R_base : float
        Contact radius of joints 1 and 2, m.
    q_cal : float
        Calibration angle of joint 1, rad.
    ratios : tuple of 6 float
        Joint-angle ratios in joint order (see :data:`PAPER_RATIOS`); entries 1 and 2 must be 1.
    link_mass, tool_mass : float
        Mass of each of the six links and of the tool point, kg.
    link_Ixx, link_Izz : float
        Link inertia about a transverse axis and about the link axis at its centre, kg m².
    k_e : float
        Elastic stiffness per joint (internal cable bundle), N m/rad.
    damping_beta : float
        Stiffness-proportional damping factor β, s: ``c_i = β K_i(P_nom)``.
    P_nom : float
        Nominal pretension per tendon, N.
    T_min, T_max : float
        Tension bounds, N (the plant saturates commands to this range).
    gravity : float
        Gravitational acceleration, m/s².

    Examples
    --------
    >>> robot = RobotParameters()
    >>> (robot.R * 1e3).round(1).tolist()
    [30.0, 30.0, 44.7, 45.1, 139.0, 124.6]
    """

    link_pitch: float = 0.040
    tool_offset: float = 0.020
    rho: float = 0.015
    R_base: float = 0.030
    q_cal: float = 0.2
    ratios: tuple[float, ...] = PAPER_RATIOS
    link_mass: float = 0.060
    tool_mass: float = 0.040
    link_Ixx: float = 1.4e-5
    link_Izz: float = 1.2e-5
    k_e: float = 0.10
    damping_beta: float = 0.02
    P_nom: float = 105.0
    T_min: float = 20.0
    T_max: float = 190.0
    gravity: float = 9.81

    def __post_init__(self) -> None:
        problems: list[str] = []
        try:
            ratios = tuple(float(r) for r in self.ratios)
        except (TypeError, ValueError):
            ratios = ()
        if len(ratios) != N_JOINTS:
            problems.append(f"ratios must hold 6 numbers, found {self.ratios!r}")
        else:
            object.__setattr__(self, "ratios", ratios)
            if ratios[0] != 1.0 or ratios[1] != 1.0:
                problems.append(f"ratios[0] and ratios[1] must be 1, found {ratios[:2]}")
            for name, r in zip(_RATIO_NAMES, ratios[2:]):
                if not (0.0 < r <= 1.0):
                    problems.append(f"{name} must be in (0, 1], found {r}")
        positive = (
            "link_pitch",
            "tool_offset",
            "rho",
            "R_base",
            "q_cal",
            "link_mass",
            "tool_mass",
            "link_Ixx",
            "link_Izz",
            "k_e",
            "damping_beta",
            "P_nom",
            "T_min",
            "T_max",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                problems.append(f"{name} must be a finite number > 0, found {value!r}")
        if not (isinstance(self.gravity, int | float) and self.gravity >= 0):
            problems.append(f"gravity must be >= 0, found {self.gravity!r}")
        if not problems:
            if self.R_base <= self.rho:
                problems.append(
                    f"R_base ({self.R_base}) must exceed the routing radius rho ({self.rho})"
                )
            if self.T_min >= self.T_max:
                problems.append(f"T_min ({self.T_min}) must be below T_max ({self.T_max})")
            elif not (self.T_min <= self.P_nom <= self.T_max):
                problems.append(f"P_nom ({self.P_nom}) must lie in [T_min, T_max]")
            if not (0 < self.q_cal < 1.0):
                problems.append(f"q_cal must be in (0, 1) rad, found {self.q_cal}")
        raise_if(problems, OptionError, "Invalid robot parameters:")
        if not problems and np.any(~np.isfinite(self.R)):
            raise OptionError(
                "Invalid robot parameters:",
                ["the contact-radius calibration has no solution for these ratios"],
            )

    # ----------------------------------------------------------------- calibration (§8)
    @cached_property
    def calibration_delta_T(self) -> float:
        """Tension difference that bends joint 1 to ``q_cal`` at ``P_nom``, N (spec §8 step 2)."""
        a_sum_base = 2.0 * math.sqrt(self.R_base**2 - self.rho**2) + 2.0 * self.R_base
        q = self.q_cal
        num = self.P_nom * a_sum_base * math.sin(q / 2) + self.k_e * q
        return num / (self.rho * math.cos(q / 2))

    @cached_property
    def R(self) -> np.ndarray:
        """Calibrated contact radius of each joint, m, shape (6,).

        For each joint the single-joint static equilibrium
        ``ρ cos(q/2) ΔT = P sin(q/2) Σ_k a_k + k_e q`` at ``q = ratio_i q_cal`` fixes
        ``s = Σ_k a_{k,i} = 2 sqrt(R² − ρ²) + 2R``, which inverts in closed form to
        ``R = (s²/4 + ρ²)/s`` (the same root a bisection would find; ``s`` is monotone in R).
        """
        out = np.empty(N_JOINTS)
        dT = self.calibration_delta_T
        for i, ratio in enumerate(self.ratios):
            if ratio == 1.0:
                out[i] = self.R_base
                continue
            q = ratio * self.q_cal
            s = (self.rho * math.cos(q / 2) * dT - self.k_e * q) / (self.P_nom * math.sin(q / 2))
            radius = (s * s / 4 + self.rho**2) / s if s > 0 else math.nan
            out[i] = radius if radius > self.rho else math.nan
        return _readonly(out)

    @cached_property
    def a_in(self) -> np.ndarray:
        """In-plane hole exit height ``sqrt(R_i² − ρ²)`` of each joint, m, shape (6,)."""
        return _readonly(np.sqrt(self.R**2 - self.rho**2))

    @cached_property
    def d(self) -> np.ndarray:
        """Signed tendon offset ``d_{k,i}``, m, shape (4, 6) (spec §1)."""
        out = np.empty((N_TENDONS, N_JOINTS))
        for i in range(N_JOINTS):
            trig = np.cos if i in PAN_JOINTS else np.sin
            out[:, i] = self.rho * trig(_TENDON_ANGLES)
        out[np.abs(out) < 1e-12 * self.rho] = 0.0
        return _readonly(out)

    @cached_property
    def a(self) -> np.ndarray:
        """Hole exit height ``a_{k,i} = sqrt(R_i² − d_{k,i}²)``, m, shape (4, 6) (spec §4)."""
        return _readonly(np.sqrt(self.R[None, :] ** 2 - self.d**2))

    @cached_property
    def a_sum(self) -> np.ndarray:
        """``Σ_k a_{k,i}`` per joint, m, shape (6,)."""
        return _readonly(self.a.sum(axis=0))

    @cached_property
    def a_mean(self) -> np.ndarray:
        """``ā_i = mean_k a_{k,i}`` per joint, m, shape (6,)."""
        return _readonly(self.a.mean(axis=0))

    # ----------------------------------------------------------------- stiffness, damping
    def stiffness(self, pretension: float | np.ndarray | None = None) -> np.ndarray:
        """Joint stiffness ``K_i(P) = ½ Σ_k a_{k,i} P + k_e`` with every tendon at ``P``.

        Parameters
        ----------
        pretension : float or array, optional
            Tension per tendon, N; defaults to ``P_nom``.  An array of shape ``(n,)`` gives
            shape ``(n, 6)``.

        Returns
        -------
        numpy.ndarray
            Stiffness per joint, N m/rad.

        Examples
        --------
        >>> RobotParameters().stiffness().round(2).tolist()
        [5.98, 5.98, 9.22, 9.3, 29.21, 26.18]
        """
        P = self.P_nom if pretension is None else np.asarray(pretension, dtype=float)
        return 0.5 * np.multiply.outer(P, self.a_sum) + self.k_e

    @cached_property
    def damping(self) -> np.ndarray:
        """Joint damping ``c_i = β K_i(P_nom)``, N m s/rad, shape (6,)."""
        return _readonly(self.damping_beta * self.stiffness())

    def __getattr__(self, name: str) -> Any:
        # ``M0`` was a property in 0.1 (now tendonkit.robot.kinematics.rest_inertia): it needs
        # the kinematics, which build on these parameters.  Kept for one release.
        from .._compat import moved_attribute

        return moved_attribute(self, name)

    @property
    def L_tip(self) -> float:
        """Distance from joint 1's contact point to the end effector when straight, m."""
        return N_JOINTS * self.link_pitch + self.tool_offset

    # ----------------------------------------------------------------- flat dictionary
    def to_dict(self) -> dict[str, float]:
        """Return the parameters as a flat ``name -> float`` dictionary.

        The ratios appear as ``ratio_3`` … ``ratio_6`` (q3/q1, q4/q2, q5/q1, q6/q2).  The names
        are valid FMI variable names.

        Examples
        --------
        >>> RobotParameters().to_dict()["ratio_5"]
        0.2053
        """
        out: dict[str, float] = {}
        for key, value in asdict(self).items():
            if key == "ratios":
                out.update(zip(_RATIO_NAMES, (float(r) for r in value[2:])))
            else:
                out[key] = float(value)
        return out

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> RobotParameters:
        """Build parameters from a flat dictionary such as :meth:`to_dict` returns.

        Missing names keep their defaults; unknown names are refused (all listed at once).

        Parameters
        ----------
        values : dict
            ``name -> number``.

        Returns
        -------
        RobotParameters
        """
        known = {f.name for f in fields(cls)} - {"ratios"}
        problems = [
            f"unknown robot parameter {name!r}"
            for name in sorted(set(values) - known - set(_RATIO_NAMES))
        ]
        numbers: dict[str, float] = {}
        for name, value in values.items():
            if name in known or name in _RATIO_NAMES:
                try:
                    numbers[name] = float(value)
                except (TypeError, ValueError):
                    problems.append(f"{name} must be a number, found {value!r}")
        raise_if(problems, OptionError, "Invalid robot parameters:")
        kwargs: dict[str, Any] = {k: v for k, v in numbers.items() if k in known}
        ratios = list(PAPER_RATIOS)
        for j, name in enumerate(_RATIO_NAMES):
            if name in numbers:
                ratios[2 + j] = numbers[name]
        kwargs["ratios"] = tuple(ratios)
        return cls(**kwargs)

    @classmethod
    def parameter_names(cls) -> tuple[str, ...]:
        """Names of the flat parameters in :meth:`to_dict` order."""
        return tuple(cls().to_dict())
