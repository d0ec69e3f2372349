"""The CERN rolling-joint snake robot: the application built on the generic toolkit.

The door of the robot room exports the robot's geometry and constants
(:class:`RobotParameters`, :data:`PAPER_RATIOS`, ...).  The modules behind it: ``parameters``
(geometry and constants), ``kinematics`` (forward/inverse kinematics, tendon statics),
``reconstruct`` (q3..q6 from q1, q2 by constant ratios), ``protocol`` (excitation and reference
trajectories), ``collect`` (data from the plant FMU), ``controllers`` and ``cosim`` (MPC in
co-simulation with the plant FMU), ``figures`` (the paper's figures) and ``study`` (the paper's
study, ``tendonkit demo``).
"""

from __future__ import annotations

from .parameters import (
    N_JOINTS,
    N_TENDONS,
    PAN_JOINTS,
    PAPER_RATIOS,
    TILT_JOINTS,
    RobotParameters,
)

__all__ = [
    "N_JOINTS",
    "N_TENDONS",
    "PAN_JOINTS",
    "PAPER_RATIOS",
    "TILT_JOINTS",
    "RobotParameters",
]
