"""Data-collection protocols of the paper: circles, pseudo-random motion and a petal reference.

Each protocol builds an end-effector reference in the base x–y plane, maps it to joint
references with the constant-ratio inverse kinematics and to tendon commands with the static
inverse per plane — the open-loop kinematic controller of plant spec §12, which knows only the
nominal robot.  Every random choice takes an explicit seed.

Examples
--------
>>> prot = circles(radii=[0.02], laps=1)
>>> prot.u.shape[1], round(float(prot.u.min()), 1) >= 20.0
(4, True)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import OptionError, raise_if
from . import PAPER_RATIOS, RobotParameters
from .kinematics import (
    commanded_tensions,
    expand_joints,
    forward_kinematics,
    inverse_kinematics,
)

__all__ = [
    "PHASES",
    "Protocol",
    "circles",
    "kinematic_controller",
    "petal",
    "pseudo_random",
]

#: Phase codes of :attr:`Protocol.phase`.
PHASES = ("ramp_in", "main", "ramp_out", "rest")


@dataclass(frozen=True)
class Protocol:
    """A commanded experiment: time, end-effector and joint references, tendon commands.

    Attributes
    ----------
    name : str
        ``"circles"``, ``"pseudo_random"`` or ``"petal"``.
    h : float
        Sample time, s.
    t : numpy.ndarray
        ``(n,)`` sample times, s, starting at 0.
    ee_ref : numpy.ndarray
        ``(n, 3)`` end-effector reference (x, y from the path, z from the kinematics), m.
    q_ref : numpy.ndarray
        ``(n, 6)`` constant-ratio joint references, rad.
    u : numpy.ndarray
        ``(n, 4)`` commanded tensions, N (clipped to the tension bounds).
    pretension : numpy.ndarray
        ``(n,)`` common-mode pretension P, N.
    segment : numpy.ndarray
        ``(n,)`` int: index of the circle (circles), move (pseudo-random) or 0 (petal).
    phase : numpy.ndarray
        ``(n,)`` int codes into :data:`PHASES`.
    radii : tuple of float
        Circle radii, m (empty for other protocols).
    info : dict
        The options the protocol was built with.
    """

    name: str
    h: float
    t: np.ndarray
    ee_ref: np.ndarray
    q_ref: np.ndarray
    u: np.ndarray
    pretension: np.ndarray
    segment: np.ndarray
    phase: np.ndarray
    radii: tuple[float, ...] = ()
    info: dict[str, object] = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.t.shape[0])

    @property
    def duration(self) -> float:
        """Length of the experiment, s (``n_samples · h``)."""
        return self.n_samples * self.h

    def mask(self, segment: int | None = None, phase: str | None = None) -> np.ndarray:
        """Boolean sample mask for one segment and/or one phase.

        Parameters
        ----------
        segment : int, optional
            Segment index (e.g. the circle number, 0-based).
        phase : str, optional
            One of :data:`PHASES`.

        Returns
        -------
        numpy.ndarray
            ``(n,)`` bool.
        """
        keep = np.ones(self.n_samples, dtype=bool)
        if segment is not None:
            keep &= self.segment == segment
        if phase is not None:
            if phase not in PHASES:
                raise OptionError(f"phase must be one of {', '.join(PHASES)}; found {phase!r}.")
            keep &= self.phase == PHASES.index(phase)
        return keep


def kinematic_controller(
    xy: np.ndarray,
    pretension: float | np.ndarray | None = None,
    robot: RobotParameters | None = None,
    ratios: Sequence[float] = PAPER_RATIOS,
    clip: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The open-loop kinematic controller of spec §12 for an end-effector path.

    Parameters
    ----------
    xy : array_like
        ``(n, 2)`` end-effector x, y reference, m.
    pretension : float or array_like, optional
        Pretension P (scalar or ``(n,)``), N; defaults to ``robot.P_nom``.
    robot : RobotParameters, optional
        Nominal parameters the controller believes in.
    ratios : sequence of float
        Joint ratios assumed by the inverse kinematics.
    clip : bool
        Saturate the commands to ``[T_min, T_max]``.

    Returns
    -------
    q_ref : numpy.ndarray
        ``(n, 6)`` joint references, rad.
    ee_ref : numpy.ndarray
        ``(n, 3)`` end-effector reference incl. the kinematic z, m.
    u : numpy.ndarray
        ``(n, 4)`` tendon commands, N.

    Examples
    --------
    >>> q, ee, u = kinematic_controller(np.array([[0.0, 0.0]]))
    >>> u.round(1).tolist()
    [[105.0, 105.0, 105.0, 105.0]]
    """
    robot = robot or RobotParameters()
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    P = robot.P_nom if pretension is None else pretension
    q12 = inverse_kinematics(xy, ratios, robot)
    q_ref = expand_joints(q12, ratios)
    ee_ref = forward_kinematics(q_ref, robot)
    u = commanded_tensions(q12, P, robot, clip=clip)
    return q_ref, ee_ref, u


def _cosine(n: int) -> np.ndarray:
    """Cosine ramp 0 → 1 sampled at ``k/n`` for k = 0..n−1."""
    return 0.5 * (1.0 - np.cos(np.pi * np.arange(n) / max(n, 1)))


def _frames(seconds: float, h: float) -> int:
    return round(float(seconds) / float(h))


def _check(problems: list[str], name: str, value: float, low: float, high: float) -> None:
    if not (np.isfinite(value) and low <= value <= high):
        problems.append(f"{name} must be in [{low:g}, {high:g}], found {value!r}")


def circles(
    radii: Sequence[float] | None = None,
    laps: float = 2.0,
    speed: float = 0.025,
    ramp_s: float = 2.0,
    rest_s: float = 1.0,
    min_period: float = 4.0,
    clockwise: bool = False,
    pretension: float | None = None,
    h: float = 0.03,
    robot: RobotParameters | None = None,
    ratios: Sequence[float] = PAPER_RATIOS,
) -> Protocol:
    """End-effector circles centred on the straight-robot tip (spec §12).

    Each circle: a cosine ramp from the centre to ``(r, 0)``, ``laps`` laps at constant speed
    (period ``max(min_period, 2πr/speed)``), a cosine ramp back to the centre and a rest.

    Parameters
    ----------
    radii : sequence of float, optional
        Radii, m; default 1, 2, …, 12 cm.
    laps : float
        Laps per circle.
    speed : float
        End-effector speed on the circle, m/s.
    ramp_s, rest_s : float
        Ramp and rest durations, s.
    min_period : float
        Shortest lap period, s.
    clockwise : bool
        Direction in the base x–y plane (counter-clockwise by default).
    pretension : float, optional
        Pretension P, N; defaults to ``robot.P_nom``.
    h : float
        Sample time, s.
    robot : RobotParameters, optional
        Nominal parameters of the controller.
    ratios : sequence of float
        Joint ratios of the inverse kinematics.

    Returns
    -------
    Protocol

    Examples
    --------
    >>> prot = circles()
    >>> prot.n_samples, round(prot.duration)
    (15173, 455)
    """
    robot = robot or RobotParameters()
    radii = tuple(float(r) for r in (np.arange(1, 13) * 0.01 if radii is None else radii))
    problems: list[str] = []
    if not radii:
        problems.append("radii must not be empty")
    for r in radii:
        _check(problems, "radius", r, 1e-4, 0.15)
    _check(problems, "laps", laps, 0.0, 100.0)
    _check(problems, "speed", speed, 1e-4, 1.0)
    _check(problems, "ramp_s", ramp_s, 0.0, 60.0)
    _check(problems, "rest_s", rest_s, 0.0, 600.0)
    _check(problems, "min_period", min_period, 0.0, 600.0)
    _check(problems, "h", h, 1e-4, 1.0)
    raise_if(problems, OptionError, "Invalid circle protocol:")
    P = robot.P_nom if pretension is None else float(pretension)
    sign = -1.0 if clockwise else 1.0
    xy_parts, seg_parts, phase_parts = [], [], []
    for index, r in enumerate(radii):
        period = max(min_period, 2 * np.pi * r / speed)
        n_ramp, n_laps, n_rest = _frames(ramp_s, h), _frames(laps * period, h), _frames(rest_s, h)
        ramp = _cosine(n_ramp)[:, None] * np.array([r, 0.0])
        theta = sign * 2 * np.pi * np.arange(n_laps) * h / period
        lap = r * np.column_stack([np.cos(theta), np.sin(theta)])
        end_theta = sign * 2 * np.pi * laps
        end = r * np.array([np.cos(end_theta), np.sin(end_theta)])
        back = (1.0 - _cosine(n_ramp))[:, None] * end
        rest = np.zeros((n_rest, 2))
        for code, part in enumerate((ramp, lap, back, rest)):
            xy_parts.append(part)
            seg_parts.append(np.full(part.shape[0], index))
            phase_parts.append(np.full(part.shape[0], code))
    xy = np.concatenate(xy_parts)
    q_ref, ee_ref, u = kinematic_controller(xy, P, robot, ratios)
    n = xy.shape[0]
    info: dict[str, object] = {
        "laps": laps,
        "speed": speed,
        "ramp_s": ramp_s,
        "rest_s": rest_s,
        "min_period": min_period,
        "clockwise": clockwise,
        "pretension": P,
    }
    return Protocol(
        name="circles",
        h=h,
        t=np.arange(n) * h,
        ee_ref=ee_ref,
        q_ref=q_ref,
        u=u,
        pretension=np.full(n, P),
        segment=np.concatenate(seg_parts),
        phase=np.concatenate(phase_parts),
        radii=radii,
        info=info,
    )


def _cosine_moves(
    rng: np.random.Generator,
    n: int,
    h: float,
    start: np.ndarray,
    draw_point: Callable[[], np.ndarray],
    move_s: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Join random way-points with cosine moves of random durations; return path and move ids."""
    out = np.empty((n, start.shape[0]))
    ids = np.empty(n, dtype=int)
    k, move, here = 0, 0, start
    while k < n:
        target = draw_point()
        m = max(1, _frames(rng.uniform(*move_s), h))
        take = min(m, n - k)
        s = _cosine(m)[:take, None]
        out[k : k + take] = here + s * (target - here)
        ids[k : k + take] = move
        k, move, here = k + take, move + 1, target
    return out, ids


def pseudo_random(
    duration: float = 240.0,
    seed: int = 0,
    radius: float = 0.12,
    move_s: tuple[float, float] = (1.0, 4.0),
    pretension_range: tuple[float, float] = (70.0, 130.0),
    pretension_move_s: tuple[float, float] = (4.0, 12.0),
    dither_sigma: float = 8.0,
    dither_fc: float = 3.0,
    h: float = 0.03,
    robot: RobotParameters | None = None,
    ratios: Sequence[float] = PAPER_RATIOS,
) -> Protocol:
    """Pseudo-random motion with a drifting pretension and per-tendon dither (spec §12).

    End-effector way-points are uniform in a disc of ``radius`` and joined by cosine moves of
    ``move_s`` seconds; the common-mode pretension moves between uniform levels in
    ``pretension_range`` (starting at ``P_nom``); each tendon gets independent white Gaussian
    noise of ``dither_sigma`` through a 2nd-order causal Butterworth at ``dither_fc``.  The
    commands are clipped to ``[T_min, T_max]``.

    Parameters
    ----------
    duration : float
        Length, s.
    seed : int
        Seed of every random choice.
    radius : float
        Disc radius of the way-points, m.
    move_s : (float, float)
        Range of the move durations, s.
    pretension_range : (float, float)
        Range of the pretension levels, N.
    pretension_move_s : (float, float)
        Range of the pretension move durations, s.
    dither_sigma : float
        Standard deviation of the white noise before the dither filter, N (0 disables).
    dither_fc : float
        Cut-off of the dither filter, Hz.
    h : float
        Sample time, s.
    robot : RobotParameters, optional
        Nominal parameters of the controller.
    ratios : sequence of float
        Joint ratios of the inverse kinematics.

    Returns
    -------
    Protocol

    Examples
    --------
    >>> a, b = pseudo_random(30.0, seed=1), pseudo_random(30.0, seed=1)
    >>> bool(np.array_equal(a.u, b.u))
    True
    """
    robot = robot or RobotParameters()
    problems: list[str] = []
    _check(problems, "duration", duration, h, 1e5)
    _check(problems, "radius", radius, 0.0, 0.15)
    _check(problems, "h", h, 1e-4, 1.0)
    _check(problems, "dither_sigma", dither_sigma, 0.0, 100.0)
    _check(problems, "dither_fc", dither_fc, 1e-3, 0.49 / h)
    for name, rng_ in (("move_s", move_s), ("pretension_move_s", pretension_move_s)):
        if not (len(rng_) == 2 and 0 < rng_[0] <= rng_[1]):
            problems.append(f"{name} must be (low, high) with 0 < low <= high, found {rng_!r}")
    lo_p, hi_p = pretension_range
    if not (robot.T_min <= lo_p <= hi_p <= robot.T_max):
        problems.append(
            f"pretension_range must lie in [{robot.T_min}, {robot.T_max}], found {pretension_range}"
        )
    if not isinstance(seed, int | np.integer) or seed < 0:
        problems.append(f"seed must be an integer >= 0, found {seed!r}")
    raise_if(problems, OptionError, "Invalid pseudo-random protocol:")
    rng = np.random.default_rng(seed)
    n = _frames(duration, h)

    def disc_point() -> np.ndarray:
        rad = radius * np.sqrt(rng.uniform())
        ang = rng.uniform(0.0, 2 * np.pi)
        return np.array([rad * np.cos(ang), rad * np.sin(ang)])

    xy, ids = _cosine_moves(rng, n, h, np.zeros(2), disc_point, move_s)
    P, _ = _cosine_moves(
        rng,
        n,
        h,
        np.array([robot.P_nom]),
        lambda: np.array([rng.uniform(lo_p, hi_p)]),
        pretension_move_s,
    )
    P = P[:, 0]
    q_ref, ee_ref, u = kinematic_controller(xy, P, robot, ratios, clip=False)
    if dither_sigma > 0:
        # lazy: heavy (scipy.signal takes 2 s to import)
        import scipy.signal

        b, a = scipy.signal.butter(2, dither_fc, fs=1.0 / h)
        u = u + scipy.signal.lfilter(b, a, dither_sigma * rng.standard_normal((n, 4)), axis=0)
    u = np.clip(u, robot.T_min, robot.T_max)
    info: dict[str, object] = {
        "seed": seed,
        "radius": radius,
        "move_s": move_s,
        "pretension_range": pretension_range,
        "pretension_move_s": pretension_move_s,
        "dither_sigma": dither_sigma,
        "dither_fc": dither_fc,
    }
    return Protocol(
        name="pseudo_random",
        h=h,
        t=np.arange(n) * h,
        ee_ref=ee_ref,
        q_ref=q_ref,
        u=u,
        pretension=P,
        segment=ids,
        phase=np.full(n, PHASES.index("main")),
        radii=(),
        info=info,
    )


def petal(
    petals: int = 3,
    amplitude: float = 0.09,
    speed: float = 0.025,
    laps: float = 1.0,
    ramp_s: float = 2.0,
    rest_s: float = 1.0,
    rotation: float = 0.0,
    pretension: float | None = None,
    h: float = 0.03,
    robot: RobotParameters | None = None,
    ratios: Sequence[float] = PAPER_RATIOS,
) -> Protocol:
    """Rose-curve reference ``r(θ) = A cos(kθ)`` for MPC tests (spec §12).

    The curve starts at ``(A, 0)`` (after a cosine ramp from the centre), is traced ``laps``
    times at a constant rate of θ chosen so that the mean end-effector speed is ``speed``, then
    the end effector ramps back and rests.  One lap covers θ ∈ [0, π) for odd k and [0, 2π)
    for even k.

    Parameters
    ----------
    petals : int
        k, the rose parameter (k petals if odd, 2k if even).
    amplitude : float
        A, m.
    speed : float
        Mean end-effector speed, m/s.
    laps : float
        Number of traversals.
    ramp_s, rest_s : float
        Ramp and rest durations, s.
    rotation : float
        Rotation of the curve about the base z axis, rad.
    pretension : float, optional
        Pretension P, N; defaults to ``robot.P_nom``.
    h : float
        Sample time, s.
    robot : RobotParameters, optional
        Nominal parameters of the controller.
    ratios : sequence of float
        Joint ratios of the inverse kinematics.

    Returns
    -------
    Protocol

    Examples
    --------
    >>> prot = petal(3, 0.08)
    >>> round(float(np.hypot(*prot.ee_ref[:, :2].T).max()), 3)
    0.08
    """
    robot = robot or RobotParameters()
    problems: list[str] = []
    if not (isinstance(petals, int | np.integer) and 1 <= petals <= 12):
        problems.append(f"petals must be an integer in [1, 12], found {petals!r}")
    _check(problems, "amplitude", amplitude, 1e-4, 0.15)
    _check(problems, "speed", speed, 1e-4, 1.0)
    _check(problems, "laps", laps, 0.0, 100.0)
    _check(problems, "ramp_s", ramp_s, 0.0, 60.0)
    _check(problems, "rest_s", rest_s, 0.0, 600.0)
    _check(problems, "h", h, 1e-4, 1.0)
    raise_if(problems, OptionError, "Invalid petal protocol:")
    k = int(petals)
    span = np.pi if k % 2 else 2 * np.pi
    fine = np.linspace(0.0, span, 20001)
    curve = amplitude * np.cos(k * fine)[:, None] * np.column_stack([np.cos(fine), np.sin(fine)])
    length = float(np.sum(np.hypot(*np.diff(curve, axis=0).T)))
    period = length / speed
    rot = np.array([[np.cos(rotation), -np.sin(rotation)], [np.sin(rotation), np.cos(rotation)]])
    n_ramp, n_main, n_rest = _frames(ramp_s, h), _frames(laps * period, h), _frames(rest_s, h)
    theta = span * np.arange(n_main) * h / period
    main = amplitude * np.cos(k * theta)[:, None] * np.column_stack([np.cos(theta), np.sin(theta)])
    start = np.array([amplitude, 0.0])
    end_theta = span * laps
    end = amplitude * np.cos(k * end_theta) * np.array([np.cos(end_theta), np.sin(end_theta)])
    parts = (
        _cosine(n_ramp)[:, None] * start,
        main,
        (1.0 - _cosine(n_ramp))[:, None] * end,
        np.zeros((n_rest, 2)),
    )
    xy = np.concatenate(parts) @ rot.T
    phase = np.concatenate([np.full(p.shape[0], code) for code, p in enumerate(parts)])
    P = robot.P_nom if pretension is None else float(pretension)
    q_ref, ee_ref, u = kinematic_controller(xy, P, robot, ratios)
    n = xy.shape[0]
    info: dict[str, object] = {
        "petals": k,
        "amplitude": amplitude,
        "speed": speed,
        "laps": laps,
        "period": period,
        "rotation": rotation,
        "pretension": P,
    }
    return Protocol(
        name="petal",
        h=h,
        t=np.arange(n) * h,
        ee_ref=ee_ref,
        q_ref=q_ref,
        u=u,
        pretension=np.full(n, P),
        segment=np.zeros(n, dtype=int),
        phase=phase,
        radii=(),
        info=info,
    )
