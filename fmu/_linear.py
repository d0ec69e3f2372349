"""The plant linearised about q = 0: the modes and small-signal gains of plant spec §7."""

from __future__ import annotations

import numpy as np

from tendonkit.fmu._config import PlantConfig
from tendonkit.fmu._effects import coupling_stiffness as _coupling_stiffness
from tendonkit.fmu._effects import gravity_linearisation as _gravity_linearisation
from tendonkit.robot import N_JOINTS, N_TENDONS, RobotParameters
from tendonkit.robot.kinematics import rest_inertia


def linearise(
    pretension: float | None = None,
    config: PlantConfig | None = None,
    robot: RobotParameters | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time linear model about q = 0 with every tendon at ``pretension``.

    ``ẋ = A x + B T`` with ``x = [q; q̇]`` and ``T`` the four tendon tensions entering the robot
    (deviations from the pretension).  Gravity stiffness (``config.mount``) and the tendon
    coupling of effect F are included when the configuration has them; friction, dead zone
    and the other effects are not linearisable and are ignored.

    Parameters
    ----------
    pretension : float, optional
        Tension per tendon, N; defaults to ``robot.P_nom``.
    config : PlantConfig, optional
    robot : RobotParameters, optional

    Returns
    -------
    A : numpy.ndarray
        ``(12, 12)``.
    B : numpy.ndarray
        ``(12, 4)``.

    Examples
    --------
    >>> A, B = linearise()
    >>> modes = np.sort(np.abs(np.linalg.eigvals(A))) / (2 * np.pi)
    >>> modes[[0, 2]].round(2)
    array([3.58, 4.66])
    """
    robot = robot or RobotParameters()
    config = config or PlantConfig()
    P = robot.P_nom if pretension is None else float(pretension)
    stiff = np.diag(robot.stiffness(P))
    stiff = stiff + _gravity_linearisation(config.mount, robot)[1]
    if config.forcelag_on:
        stiff = stiff + _coupling_stiffness(config.forcelag_kt, robot)
    m_inv = np.linalg.inv(rest_inertia(robot))
    a = np.zeros((2 * N_JOINTS, 2 * N_JOINTS))
    a[:N_JOINTS, N_JOINTS:] = np.eye(N_JOINTS)
    a[N_JOINTS:, :N_JOINTS] = -m_inv @ stiff
    a[N_JOINTS:, N_JOINTS:] = -m_inv * robot.damping[None, :]
    b = np.zeros((2 * N_JOINTS, N_TENDONS))
    b[N_JOINTS:] = m_inv @ robot.d.T
    return a, b
