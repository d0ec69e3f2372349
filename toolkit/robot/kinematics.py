"""Rolling-joint kinematics, constant-ratio inverse kinematics and the static tension inverse.

Implements the exact kinematics of plant spec §3 and the open-loop kinematic controller of
§12 steps 1–3.  Every function is vectorised over samples: joint angles are ``(n, 6)`` arrays
(a single ``(6,)`` vector is accepted and gives un-batched results), positions ``(n, 3)`` in
metres, Jacobians ``(n, 3, 6)``.  The module is shared by the plant, the model-FMU export and
MPC, so it depends on nothing but numpy and :mod:`tendonkit.robot`.

Rolling joint i (contact radius R_i) has the exact relative transform

    A_i(q) = Tz(−R_i) · Rot_i(q/2) · Tz(2R_i) · Rot_i(q/2) · Tz(−R_i),

pan joints (1, 3, 5) turn about the parent's +y axis, tilt joints (2, 4, 6) about its −x axis,
and ``T_EE(q) = A_1 Tz(ℓ) A_2 Tz(ℓ) … A_6 Tz(ℓ) Tz(ℓ_tool)``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import DataError, OptionError
from . import N_JOINTS, PAN_JOINTS, PAPER_RATIOS, RobotParameters

__all__ = [
    "ChainFrames",
    "commanded_tensions",
    "expand_joints",
    "forward_kinematics",
    "frames",
    "gravity_torque",
    "inverse_kinematics",
    "jacobian",
    "link_jacobians",
    "mass_matrix",
    "ratio_matrix",
    "scalar_forward_kinematics",
    "static_tension_difference",
]

_DEFAULT = RobotParameters()


def _robot(robot: RobotParameters | None) -> RobotParameters:
    return _DEFAULT if robot is None else robot


def _as_batch(q: np.ndarray | Sequence[float], width: int, name: str) -> tuple[np.ndarray, bool]:
    """Return ``q`` as a float ``(n, width)`` array and whether the input was one sample."""
    arr = np.asarray(q, dtype=float)
    single = arr.ndim == 1
    if single:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise DataError(f"{name} must have shape ({width},) or (n, {width}); found {arr.shape}.")
    return arr, single


def _rotation(i: int, angle: np.ndarray) -> np.ndarray:
    """Rotation of joint ``i`` (0-based) by ``angle`` (n,), shape (n, 3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros((angle.shape[0], 3, 3))
    if i in PAN_JOINTS:  # about +y: e_z -> (sin, 0, cos)
        out[:, 0, 0] = c
        out[:, 0, 2] = s
        out[:, 1, 1] = 1.0
        out[:, 2, 0] = -s
        out[:, 2, 2] = c
    else:  # about -x: e_z -> (0, sin, cos)
        out[:, 0, 0] = 1.0
        out[:, 1, 1] = c
        out[:, 1, 2] = s
        out[:, 2, 1] = -s
        out[:, 2, 2] = c
    return out


def _local_axis(i: int) -> np.ndarray:
    return np.array([0.0, 1.0, 0.0]) if i in PAN_JOINTS else np.array([-1.0, 0.0, 0.0])


@dataclass(frozen=True)
class ChainFrames:
    """World (base-frame) geometry of the chain for a batch of joint vectors.

    Attributes
    ----------
    rotations : numpy.ndarray
        ``(n, 7, 3, 3)`` orientation of link 0 (base, identity) … link 6.
    bottoms : numpy.ndarray
        ``(n, 6, 3)`` bottom contact point of links 1 … 6.
    tops : numpy.ndarray
        ``(n, 7, 3)`` top contact point of link 0 (the origin) … link 6.
    contacts : numpy.ndarray
        ``(n, 6, 3)`` instantaneous contact point c_i of each rolling joint.
    axes : numpy.ndarray
        ``(n, 6, 3)`` joint axis a_i in base coordinates.
    centres : numpy.ndarray
        ``(n, 7, 3)`` mass centres: links 1 … 6 (mid-pitch) and the tool point (= ee).
    ee : numpy.ndarray
        ``(n, 3)`` end-effector point.
    """

    rotations: np.ndarray
    bottoms: np.ndarray
    tops: np.ndarray
    contacts: np.ndarray
    axes: np.ndarray
    centres: np.ndarray
    ee: np.ndarray


def frames(q: np.ndarray, robot: RobotParameters | None = None) -> ChainFrames:
    """Compute every link frame, contact point and joint axis of the chain.

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.

    Returns
    -------
    ChainFrames
        Batched geometry (always with a leading sample axis).

    Examples
    --------
    >>> frames([0.0] * 6).ee.round(3)
    array([[0.  , 0.  , 0.26]])
    """
    robot = _robot(robot)
    qb, _ = _as_batch(q, N_JOINTS, "q")
    n = qb.shape[0]
    rot = np.empty((n, N_JOINTS + 1, 3, 3))
    rot[:, 0] = np.eye(3)
    tops = np.zeros((n, N_JOINTS + 1, 3))
    bottoms = np.empty((n, N_JOINTS, 3))
    contacts = np.empty((n, N_JOINTS, 3))
    axes = np.empty((n, N_JOINTS, 3))
    centres = np.empty((n, N_JOINTS + 1, 3))
    ell = robot.link_pitch
    for i in range(N_JOINTS):
        radius = robot.R[i]
        qi = qb[:, i]
        parent = rot[:, i]
        # A rotation about one local axis mixes two columns of the parent's orientation: column
        # arithmetic on (n, 3) arrays instead of n tiny 3x3 matrix products (same numbers).
        pan = i in PAN_JOINTS
        a, b = (0, 2) if pan else (1, 2)  # the bending column and the z column
        ch, sh = np.cos(0.5 * qi)[:, None], np.sin(0.5 * qi)[:, None]
        c, s = np.cos(qi)[:, None], np.sin(qi)[:, None]
        # p_i(q) = R (2 sin(q/2) - sin q) e_bend + R (2 cos(q/2) - 1 - cos q) e_z
        bend = radius * (2 * sh - s)
        lift = radius * (2 * ch - 1 - c)
        bottoms[:, i] = tops[:, i] + parent[:, :, a] * bend + parent[:, :, b] * lift
        half_z = sh * parent[:, :, a] + ch * parent[:, :, b]
        contacts[:, i] = tops[:, i] - radius * parent[:, :, 2] + radius * half_z
        axes[:, i] = parent[:, :, 1] if pan else -parent[:, :, 0]
        child = rot[:, i + 1]
        child[:] = parent
        child[:, :, a] = c * parent[:, :, a] - s * parent[:, :, b]
        child[:, :, b] = s * parent[:, :, a] + c * parent[:, :, b]
        link_z = rot[:, i + 1, :, 2]
        tops[:, i + 1] = bottoms[:, i] + ell * link_z
        centres[:, i] = bottoms[:, i] + 0.5 * ell * link_z
    ee = tops[:, N_JOINTS] + robot.tool_offset * rot[:, N_JOINTS, :, 2]
    centres[:, N_JOINTS] = ee
    return ChainFrames(rot, bottoms, tops, contacts, axes, centres, ee)


def forward_kinematics(q: np.ndarray, robot: RobotParameters | None = None) -> np.ndarray:
    """End-effector position for joint angles ``q`` (exact rolling-joint kinematics).

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.

    Returns
    -------
    numpy.ndarray
        End-effector position in the base frame, m: ``(n, 3)``, or ``(3,)`` for one sample.

    Examples
    --------
    >>> (forward_kinematics([0.2, 0, 0, 0, 0, 0]) * 1e3).round(1)
    array([ 51.7,   0. , 255.1])
    """
    robot = _robot(robot)
    qb, single = _as_batch(q, N_JOINTS, "q")
    n = qb.shape[0]
    if n <= _SCALAR_FK_MAX:  # per-step use (plant FMU): plain floats beat tiny arrays
        fk = scalar_forward_kinematics(robot)
        ee = np.array([fk(row) for row in qb.tolist()]).reshape(n, 3)
        return ee[0] if single else ee
    # Columns of the current link orientation, each (n, 3); rotating about one axis only mixes
    # two columns, which keeps this far cheaper than stacked 3x3 products.
    cols = [np.zeros((n, 3)) for _ in range(3)]
    for axis in range(3):
        cols[axis][:, axis] = 1.0
    pos = np.zeros((n, 3))
    for i in range(N_JOINTS):
        radius, qi = robot.R[i], qb[:, i]
        s_half, c_half = np.sin(0.5 * qi), np.cos(0.5 * qi)
        s, c = np.sin(qi), np.cos(qi)
        bend = (radius * (2 * s_half - s))[:, None]
        lift = (radius * (2 * c_half - 1 - c))[:, None]
        b = 0 if i in PAN_JOINTS else 1  # pan bends toward the link's x axis, tilt toward y
        pos += bend * cols[b] + lift * cols[2]
        sc, cc = s[:, None], c[:, None]
        cols[b], cols[2] = cc * cols[b] - sc * cols[2], sc * cols[b] + cc * cols[2]
        pos += robot.link_pitch * cols[2]
    ee = pos + robot.tool_offset * cols[2]
    return ee[0] if single else ee


_SCALAR_FK_MAX = 4


def scalar_forward_kinematics(
    robot: RobotParameters | None = None,
) -> Callable[[Sequence[float]], list[float]]:
    """Return a fast end-effector function for one joint vector, on plain Python floats.

    The returned function computes exactly what :func:`forward_kinematics` computes for one
    sample (the same floating-point operations in the same order), without numpy: about four
    times faster than a numpy call for a single joint vector, which is what a per-frame
    simulation step needs.  The geometry of ``robot`` is fixed when the function is made.

    Parameters
    ----------
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.

    Returns
    -------
    callable
        ``fk(q) -> [x, y, z]``: joint angles (6 floats, rad) to the end-effector position in
        the base frame, m.

    Examples
    --------
    >>> fk = scalar_forward_kinematics()
    >>> [round(v * 1e3, 1) for v in fk([0.2, 0.0, 0.0, 0.0, 0.0, 0.0])]
    [51.7, 0.0, 255.1]
    """
    robot = _robot(robot)
    # Per joint: contact radius and whether it bends toward the link's x (pan) or y (tilt) axis.
    joints = tuple((float(r), i in PAN_JOINTS) for i, r in enumerate(robot.R.tolist()))
    ell, tool = float(robot.link_pitch), float(robot.tool_offset)
    sin, cos = math.sin, math.cos

    def fk(q: Sequence[float]) -> list[float]:
        # Columns x, y, z of the current link orientation and the contact point p; a rotation
        # about one joint axis mixes only the bending column with the z column.
        x0, x1, x2 = 1.0, 0.0, 0.0
        y0, y1, y2 = 0.0, 1.0, 0.0
        z0, z1, z2 = 0.0, 0.0, 1.0
        p0 = p1 = p2 = 0.0
        for (radius, pan), qi in zip(joints, q, strict=True):
            s, c = sin(qi), cos(qi)
            bend = radius * (2 * sin(0.5 * qi) - s)
            lift = radius * (2 * cos(0.5 * qi) - 1 - c)
            if pan:
                n0, n1, n2 = s * x0 + c * z0, s * x1 + c * z1, s * x2 + c * z2
                p0 = p0 + bend * x0 + lift * z0 + ell * n0
                p1 = p1 + bend * x1 + lift * z1 + ell * n1
                p2 = p2 + bend * x2 + lift * z2 + ell * n2
                x0, x1, x2 = c * x0 - s * z0, c * x1 - s * z1, c * x2 - s * z2
            else:
                n0, n1, n2 = s * y0 + c * z0, s * y1 + c * z1, s * y2 + c * z2
                p0 = p0 + bend * y0 + lift * z0 + ell * n0
                p1 = p1 + bend * y1 + lift * z1 + ell * n1
                p2 = p2 + bend * y2 + lift * z2 + ell * n2
                y0, y1, y2 = c * y0 - s * z0, c * y1 - s * z1, c * y2 - s * z2
            z0, z1, z2 = n0, n1, n2
        return [p0 + tool * z0, p1 + tool * z1, p2 + tool * z2]

    return fk


def _point_jacobian(fr: ChainFrames, point: np.ndarray, link: int) -> np.ndarray:
    """``J_v`` of a point (n, 3) rigidly attached to ``link`` (1..6): (n, 3, 6)."""
    n = point.shape[0]
    jac = np.zeros((n, 3, N_JOINTS))
    for i in range(link):
        jac[:, :, i] = np.cross(fr.axes[:, i], point - fr.contacts[:, i])
    return jac


def jacobian(q: np.ndarray, robot: RobotParameters | None = None) -> np.ndarray:
    """Linear-velocity Jacobian of the end effector, ``d ee / d q``.

    Column i is ``a_i × (ee − c_i)``: during rolling, the distal chain turns about the
    instantaneous contact point ``c_i`` (spec §3).

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.

    Returns
    -------
    numpy.ndarray
        ``(n, 3, 6)``, or ``(3, 6)`` for one sample, m/rad.

    Examples
    --------
    >>> jacobian([0.0] * 6)[0].round(3)
    array([0.26, 0.  , 0.18, 0.  , 0.1 , 0.  ])
    """
    _, single = _as_batch(q, N_JOINTS, "q")
    fr = frames(q, robot)
    jac = _point_jacobian(fr, fr.ee, N_JOINTS)
    return jac[0] if single else jac


def link_jacobians(
    q: np.ndarray, robot: RobotParameters | None = None
) -> tuple[np.ndarray, np.ndarray, ChainFrames]:
    """Jacobians of the seven mass centres (links 1–6 and the tool point).

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.

    Returns
    -------
    J_v : numpy.ndarray
        ``(n, 7, 3, 6)`` linear-velocity Jacobians of the mass centres.
    J_w : numpy.ndarray
        ``(n, 7, 3, 6)`` angular-velocity Jacobians of the bodies (the tool shares link 6's).
    frames : ChainFrames
        The geometry they were computed from.
    """
    fr = frames(q, robot)
    n = fr.ee.shape[0]
    jv = np.zeros((n, N_JOINTS + 1, 3, N_JOINTS))
    jw = np.zeros((n, N_JOINTS + 1, 3, N_JOINTS))
    for j in range(N_JOINTS + 1):
        link = min(j + 1, N_JOINTS)
        jv[:, j] = _point_jacobian(fr, fr.centres[:, j], link)
        for i in range(link):
            jw[:, j, :, i] = fr.axes[:, i]
    return jv, jw, fr


def mass_matrix(q: np.ndarray, robot: RobotParameters | None = None) -> np.ndarray:
    """Configuration-dependent joint-space inertia ``M(q)`` (spec §5 reference model).

    ``M = Σ_j m_j J_vjᵀ J_vj + J_ωjᵀ R_j I_j R_jᵀ J_ωj`` over the six links (solid cylinders,
    mass centre at mid-pitch) plus the tool point mass.

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    robot : RobotParameters, optional
        Geometry and masses; the nominal robot by default.

    Returns
    -------
    numpy.ndarray
        ``(n, 6, 6)``, or ``(6, 6)`` for one sample, kg m².

    Examples
    --------
    >>> (np.diag(mass_matrix([0.0] * 6)) * 1e3).round(2)
    array([9.65, 5.97, 3.37, 1.67, 0.67, 0.18])
    """
    robot = _robot(robot)
    _, single = _as_batch(q, N_JOINTS, "q")
    jv, jw, fr = link_jacobians(q, robot)
    inertia = np.diag([robot.link_Ixx, robot.link_Ixx, robot.link_Izz])
    m = np.full(N_JOINTS + 1, robot.link_mass)
    m[N_JOINTS] = robot.tool_mass
    out = np.einsum("j,njai,njak->nik", m, jv, jv)
    rots = fr.rotations[:, 1:]
    world_inertia = rots @ inertia @ np.swapaxes(rots, -1, -2)
    out += np.einsum("njai,njab,njbk->nik", jw[:, :N_JOINTS], world_inertia, jw[:, :N_JOINTS])
    return out[0] if single else out


def rest_inertia(robot: RobotParameters | None = None) -> np.ndarray:
    """Joint-space inertia at q = 0, kg m², shape (6, 6) (block-diagonal pan/tilt), read-only.

    :func:`mass_matrix` at the straight configuration, computed once per robot.

    Examples
    --------
    >>> (np.diag(rest_inertia()) * 1e3).round(2)
    array([9.65, 5.97, 3.37, 1.67, 0.67, 0.18])
    """
    return _rest_inertia(_robot(robot))


@functools.lru_cache(maxsize=16)
def _rest_inertia(robot: RobotParameters) -> np.ndarray:
    m0 = mass_matrix(np.zeros(N_JOINTS), robot)
    m0.setflags(write=False)
    return m0


def gravity_torque(
    q: np.ndarray, g_base: np.ndarray | Sequence[float], robot: RobotParameters | None = None
) -> np.ndarray:
    """Exact gravity torque ``τ_g = Σ_j m_j J_vjᵀ g_B`` (spec §5 reference model).

    Parameters
    ----------
    q : array_like
        Joint angles, ``(n, 6)`` or ``(6,)``, rad.
    g_base : array_like
        Gravity vector in base coordinates, m/s², shape (3,).
    robot : RobotParameters, optional
        Masses and geometry; the nominal robot by default.

    Returns
    -------
    numpy.ndarray
        ``(n, 6)``, or ``(6,)`` for one sample, N m.
    """
    robot = _robot(robot)
    _, single = _as_batch(q, N_JOINTS, "q")
    jv, _, _ = link_jacobians(q, robot)
    m = np.full(N_JOINTS + 1, robot.link_mass)
    m[N_JOINTS] = robot.tool_mass
    out = np.einsum("j,njai,a->ni", m, jv, np.asarray(g_base, dtype=float))
    return out[0] if single else out


# --------------------------------------------------------------------- constant ratios
def ratio_matrix(ratios: Sequence[float] = PAPER_RATIOS) -> np.ndarray:
    """Matrix ``E`` (6, 2) with ``q = E @ (q1, q2)`` for constant joint ratios.

    Parameters
    ----------
    ratios : sequence of float
        Six per-joint ratios in joint order (see :data:`tendonkit.robot.PAPER_RATIOS`), or the
        four free ones ``(q3/q1, q4/q2, q5/q1, q6/q2)``.

    Returns
    -------
    numpy.ndarray
        Shape (6, 2).

    Examples
    --------
    >>> ratio_matrix()[:, 0]
    array([1.    , 0.    , 0.6493, 0.    , 0.2053, 0.    ])
    """
    r = [float(x) for x in ratios]
    if len(r) == 4:
        r = [1.0, 1.0, *r]
    if len(r) != N_JOINTS:
        raise OptionError(f"ratios must hold 6 (or 4) numbers; found {len(r)}: {r}.")
    e = np.zeros((N_JOINTS, 2))
    for i in range(N_JOINTS):
        e[i, 0 if i in PAN_JOINTS else 1] = r[i]
    return e


def expand_joints(q12: np.ndarray, ratios: Sequence[float] = PAPER_RATIOS) -> np.ndarray:
    """Reconstruct all six joints from (q1, q2) with constant ratios.

    Parameters
    ----------
    q12 : array_like
        ``(n, 2)`` or ``(2,)`` base-joint angles (q1 pan, q2 tilt), rad.
    ratios : sequence of float
        See :func:`ratio_matrix`.

    Returns
    -------
    numpy.ndarray
        ``(n, 6)`` or ``(6,)``: ``(q1, q2, r3 q1, r4 q2, r5 q1, r6 q2)``.

    Examples
    --------
    >>> expand_joints([0.1, -0.2]).round(4)
    array([ 0.1   , -0.2   ,  0.0649, -0.1288,  0.0205, -0.0458])
    """
    arr, single = _as_batch(q12, 2, "q12")
    out = arr @ ratio_matrix(ratios).T
    return out[0] if single else out


def inverse_kinematics(
    xy: np.ndarray,
    ratios: Sequence[float] = PAPER_RATIOS,
    robot: RobotParameters | None = None,
    iterations: int = 8,
) -> np.ndarray:
    """Constant-ratio inverse kinematics: end-effector (x, y) to (q1, q2) (spec §12 step 1).

    Newton's method on ``FK(expand_joints(q12))[:2] = xy``, vectorised over all samples,
    started from ``q12 = xy / (1.6 L_tip)``.

    Parameters
    ----------
    xy : array_like
        ``(n, 2)`` or ``(2,)`` end-effector x, y in the base frame, m.
    ratios : sequence of float
        Joint ratios assumed by the controller.
    robot : RobotParameters, optional
        Geometry; the nominal robot by default.
    iterations : int
        Newton iterations (8 reach machine precision on the 12 cm disc).

    Returns
    -------
    numpy.ndarray
        ``(n, 2)`` or ``(2,)`` joint angles (q1, q2), rad.

    Examples
    --------
    >>> q12 = inverse_kinematics([0.05, 0.0])
    >>> bool(abs(forward_kinematics(expand_joints(q12))[0] - 0.05) < 1e-12)
    True
    """
    robot = _robot(robot)
    target, single = _as_batch(xy, 2, "xy")
    e = ratio_matrix(ratios)
    q12 = target / (1.6 * robot.L_tip)
    for _ in range(iterations):
        q = q12 @ e.T
        fr = frames(q, robot)
        resid = fr.ee[:, :2] - target
        if not resid.size or np.max(np.abs(resid)) <= 1e-15:  # 1 fm: converged (4-5 steps)
            break
        jac = _point_jacobian(fr, fr.ee, N_JOINTS)[:, :2, :] @ e
        q12 = q12 - np.linalg.solve(jac, resid[:, :, None])[:, :, 0]
    return q12[0] if single else q12


def static_tension_difference(
    q12: np.ndarray,
    pretension: float | np.ndarray,
    robot: RobotParameters | None = None,
) -> np.ndarray:
    """Static inverse per plane: tension difference holding (q1, q2) (spec §12 step 2).

    ``ΔT = [P Σ_k a_{k,i} sin(q_i/2) + k_e q_i] / (ρ cos(q_i/2))`` for i = 1 (pan, T1 − T3)
    and i = 2 (tilt, T2 − T4), with both pair sums at ``2P``.

    Parameters
    ----------
    q12 : array_like
        ``(n, 2)`` or ``(2,)`` joint angles (q1, q2), rad.
    pretension : float or array_like
        Pretension P per sample, N (scalar or ``(n,)``).
    robot : RobotParameters, optional
        Nominal parameters the controller believes in.

    Returns
    -------
    numpy.ndarray
        ``(n, 2)`` or ``(2,)``: (T1 − T3, T2 − T4), N.

    Examples
    --------
    >>> round(float(static_tension_difference([0.2, 0.0], 105.0)[0]), 2)
    79.98
    """
    robot = _robot(robot)
    arr, single = _as_batch(q12, 2, "q12")
    P = np.asarray(pretension, dtype=float).reshape(-1, 1) * np.ones((arr.shape[0], 1))
    half = 0.5 * arr
    a_sum = robot.a_sum[:2][None, :]
    dT = (P * a_sum * np.sin(half) + robot.k_e * arr) / (robot.rho * np.cos(half))
    return dT[0] if single else dT


def commanded_tensions(
    q12: np.ndarray,
    pretension: float | np.ndarray,
    robot: RobotParameters | None = None,
    clip: bool = True,
) -> np.ndarray:
    """Tendon commands of the open-loop kinematic controller (spec §12 step 3).

    ``u = (P + ΔT_x/2, P + ΔT_y/2, P − ΔT_x/2, P − ΔT_y/2)``, clipped to ``[T_min, T_max]``.

    Parameters
    ----------
    q12 : array_like
        ``(n, 2)`` or ``(2,)`` joint angles (q1, q2), rad.
    pretension : float or array_like
        Pretension P, N (scalar or ``(n,)``).
    robot : RobotParameters, optional
        Nominal parameters the controller believes in.
    clip : bool
        Saturate to the tension bounds.

    Returns
    -------
    numpy.ndarray
        ``(n, 4)`` or ``(4,)`` commanded tensions (T1, T2, T3, T4), N.

    Examples
    --------
    >>> commanded_tensions([0.2, 0.0], 105.0).round().tolist()
    [145.0, 105.0, 65.0, 105.0]
    """
    robot = _robot(robot)
    arr, single = _as_batch(q12, 2, "q12")
    dT = static_tension_difference(arr, pretension, robot)
    P = np.asarray(pretension, dtype=float).reshape(-1, 1) * np.ones((arr.shape[0], 1))
    u = np.concatenate([P + 0.5 * dT, P - 0.5 * dT], axis=1)
    if clip:
        u = np.clip(u, robot.T_min, robot.T_max)
    return u[0] if single else u
