"""Tendon mechanics, gravity, hidden-effect operators and the exact-ZOH step table of the plant.

Private helpers of :mod:`tendonkit.fmu.plant` (spec §4, §9, §10).  Everything here is a pure
function of its arguments; the plant holds the state.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.linalg

from tendonkit.robot import N_JOINTS, RobotParameters
from tendonkit.robot.kinematics import gravity_torque, rest_inertia

#: Where in the frame the held nonlinear remainder is evaluated, as a fraction of h: the angles
#: are predicted as q̂ = q + PREDICT·h·q̇ from the state at the frame start.  Spec §9 uses the
#: frame start (0); the mid-frame prediction (0.5) costs nothing extra and cuts the error against
#: a tight-tolerance integrator about tenfold on the pseudo-random protocol.
PREDICT = 0.5

#: Tension grid of the step table: S_n = S_MIN, S_MIN + 1, ..., S_MAX (N).
S_MIN = 40.0
S_MAX = 800.0


def gravity_vector(mount: str, g: float) -> np.ndarray:
    """Gravity in base coordinates, ``g_B = R_mountᵀ (0, 0, −g)``, for a mounting option."""
    vectors = {
        "none": (0.0, 0.0, 0.0),
        "up": (0.0, 0.0, -g),  # robot axis along world +z
        "down": (0.0, 0.0, g),  # hanging
        "horiz_tilt": (0.0, -g, 0.0),  # base y (tilt plane) vertical, +y up
        "horiz_pan": (-g, 0.0, 0.0),  # base x (pan plane) vertical, +x up
    }
    return np.array(vectors[mount])


def gravity_linearisation(mount: str, robot: RobotParameters) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(G0, K_G)``: gravity torque at q = 0 and its stiffness ``−∂τ_g/∂q``.

    ``K_G`` comes from central differences of the exact ``τ_g(q)`` (step 1e-5 rad; the error
    is ~1e-10 of the entries, far below anything the plant resolves).
    """
    g_b = gravity_vector(mount, robot.gravity)
    if not np.any(g_b):
        return np.zeros(N_JOINTS), np.zeros((N_JOINTS, N_JOINTS))
    eps = 1e-5
    probes = np.concatenate([np.eye(N_JOINTS) * eps, -np.eye(N_JOINTS) * eps, np.zeros((1, 6))])
    tau = gravity_torque(probes, g_b, robot)
    k_g = -(tau[:N_JOINTS] - tau[N_JOINTS : 2 * N_JOINTS]).T / (2 * eps)
    k_g = 0.5 * (k_g + k_g.T)  # conservative: symmetric up to rounding
    return tau[-1].copy(), k_g


def tendon_torque(q: np.ndarray, tensions: np.ndarray, robot: RobotParameters) -> np.ndarray:
    """Generalised tendon torque ``τ_t,i = Σ_k T_{k,i} [d_{k,i} cos(q_i/2) − a_{k,i} sin(q_i/2)]``.

    Parameters
    ----------
    q : numpy.ndarray
        Joint angles ``(..., 6)``.
    tensions : numpy.ndarray
        Either base tensions ``(..., 4)`` (every gap sees the same tension) or gap tensions
        ``(..., 4, 6)``.
    robot : RobotParameters

    Returns
    -------
    numpy.ndarray
        ``(..., 6)``, N m.
    """
    tensions = np.asarray(tensions, dtype=float)
    if tensions.shape[-1] == 4:
        tensions = tensions[..., :, None]
    half = 0.5 * np.asarray(q, dtype=float)
    drive = (tensions * robot.d).sum(axis=-2)
    restore = (tensions * robot.a).sum(axis=-2)
    return np.cos(half) * drive - np.sin(half) * restore


def tendon_length_change(q: np.ndarray, robot: RobotParameters) -> np.ndarray:
    """``L_k(q) − L_k(0)`` summed over the six gaps, m, shape ``(..., 4)`` (spec §4)."""
    half = 0.5 * np.asarray(q, dtype=float)[..., None, :]
    per_gap = 2.0 * (robot.a * (1.0 - np.cos(half)) - robot.d * np.sin(half))
    return per_gap.sum(axis=-1)


def length_change_scalar(
    q: list[float], a_rows: list[list[float]], d_rows: list[list[float]]
) -> list[float]:
    """:func:`tendon_length_change` for one joint vector on plain floats (same arithmetic).

    ``a_rows`` and ``d_rows`` are ``robot.a`` and ``robot.d`` as nested lists (4 × 6).
    """
    halves = [0.5 * v for v in q]
    versines = [1.0 - math.cos(h) for h in halves]
    sines = [math.sin(h) for h in halves]
    return [
        sum([2.0 * (a * c - d * s) for a, d, c, s in zip(ak, dk, versines, sines, strict=True)])
        for ak, dk in zip(a_rows, d_rows, strict=True)
    ]


def coupling_stiffness(k_t: float, robot: RobotParameters) -> np.ndarray:
    """Tendon-spring coupling ``K_t = k_t Σ_k d_k d_kᵀ`` (effect F), N m/rad."""
    return k_t * robot.d.T @ robot.d


@lru_cache(maxsize=32)
def step_table(
    robot: RobotParameters,
    h: float,
    mount: str,
    k_t: float,
    extra: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Build the stacked exact-ZOH step matrices of spec §9, one per tension grid point.

    For ``x = [q; q̇]`` and ``A(S) = [[0, I], [−M0⁻¹K(S), −M0⁻¹C]]``, ``B = [0; M0⁻¹]`` with
    ``K(S) = diag(½ ā S + k_e) + K_G + K_t``, the frame map is
    ``x⁺ = Φ x + Γ f`` with ``f = τ_t(q̂) + (½ ā S_n + K_t) q̂ + G0 + τ_x``.  The linear terms of
    ``f`` are folded into the matrix, so each returned matrix ``M_n`` acts on

        z = [x (12), sin/cos half-angle products (12), τ_x (6, only if ``extra``), 1]

    where the 12 products are ``[sin(q̂/2) ⊙ (−Σ_k a T), cos(q̂/2) ⊙ (Σ_k d T)]``, whose two
    halves sum to ``τ_t(q̂)``, with ``q̂ = q + PREDICT·h·q̇`` the point at which the held
    remainder is evaluated.  Rows 12–23 of ``M_n z`` return ``[q̂⁺/2, q̂⁺/2 + π/2]`` so that
    one ``sin`` call yields the next frame's half-angle sines and cosines.

    Returns
    -------
    matrices : numpy.ndarray
        ``(n_grid, 24, n_z)`` read-only.
    gamma : numpy.ndarray
        ``(n_grid, 12, 6)`` read-only input matrices Γ_n (for diagnostics and tests).
    """
    n = N_JOINTS
    s_grid = np.arange(S_MIN, S_MAX + 0.5, 1.0)
    g0, k_g = gravity_linearisation(mount, robot)
    k_t_mat = coupling_stiffness(k_t, robot) if k_t > 0 else np.zeros((n, n))
    m_inv = np.linalg.inv(rest_inertia(robot))
    geometric = 0.5 * np.multiply.outer(s_grid, robot.a_mean)  # (N, 6)
    stiff = np.zeros((s_grid.size, n, n))
    stiff[:, np.arange(n), np.arange(n)] = geometric + robot.k_e
    stiff += k_g + k_t_mat
    aug = np.zeros((s_grid.size, 3 * n, 3 * n))
    aug[:, :n, n : 2 * n] = np.eye(n)
    aug[:, n : 2 * n, :n] = -m_inv @ stiff
    aug[:, n : 2 * n, n : 2 * n] = -m_inv * robot.damping[None, :]
    aug[:, n : 2 * n, 2 * n :] = m_inv
    expo = scipy.linalg.expm(aug * h)
    phi = expo[:, : 2 * n, : 2 * n]
    gamma = expo[:, : 2 * n, 2 * n :]
    # Fold the linear remainder (½ ā S_n + K_t) q̂ back in, q̂ = P x the evaluation point:
    # x⁺ = (Φ + Γ L P) x + Γ (...).
    predict = np.hstack([np.eye(n), PREDICT * h * np.eye(n)])  # (6, 12)
    lin = np.zeros((s_grid.size, n, n))
    lin[:, np.arange(n), np.arange(n)] = geometric
    lin += k_t_mat
    n_z = 2 * n + 2 * n + (n if extra else 0) + 1
    mats = np.zeros((s_grid.size, 4 * n, n_z))
    mats[:, : 2 * n, : 2 * n] = phi + gamma @ lin @ predict
    mats[:, : 2 * n, 2 * n : 3 * n] = gamma
    mats[:, : 2 * n, 3 * n : 4 * n] = gamma
    if extra:
        mats[:, : 2 * n, 4 * n : 5 * n] = gamma
    mats[:, : 2 * n, -1] = gamma @ g0
    half = 0.5 * (predict @ mats[:, : 2 * n])  # q̂⁺/2 of the next frame
    mats[:, 2 * n : 3 * n] = half
    mats[:, 3 * n : 4 * n] = half
    mats[:, 3 * n : 4 * n, -1] += 0.5 * np.pi
    mats.setflags(write=False)
    gamma.setflags(write=False)
    return mats, gamma


def table_index(total_tension: np.ndarray | float) -> np.ndarray:
    """Grid index ``n = round(S − S_MIN)``, clipped to the table."""
    idx = np.rint(np.asarray(total_tension, dtype=float) - S_MIN)
    return np.clip(idx, 0, S_MAX - S_MIN).astype(np.intp)


def softplus_deadzone(tension: np.ndarray, threshold: float, width: float) -> np.ndarray:
    """Effect Z: ``T_eff = w ln(1 + exp((T − T_dz)/w))`` (overflow-safe)."""
    return width * np.logaddexp(0.0, (tension - threshold) / width)


def softplus_scalar(tension: float, threshold: float, width: float) -> float:
    """:func:`softplus_deadzone` for one tension on plain floats (same arithmetic)."""
    x = (tension - threshold) / width
    return width * (x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x)))


def biquad_step(
    x: list[float], state: list[list[float]], coefficients: tuple[float, ...]
) -> tuple[list[float], list[list[float]]]:
    """One sample of a 2nd-order filter on each channel, as ``scipy.signal.lfilter`` does it.

    Transposed direct form II, operation for operation like scipy's C loop, so a filter run
    sample by sample through this function equals ``lfilter`` on the whole record.

    Parameters
    ----------
    x : list of float
        One input sample per channel.
    state : list of 2 lists of float
        ``zi`` of ``lfilter`` (2 × channels).
    coefficients : tuple of 5 float
        ``(b0, b1, b2, a1, a2)`` normalised so that ``a0 = 1``.

    Returns
    -------
    y : list of float
        The filtered sample.
    state : list of 2 lists of float
        The new filter state.
    """
    b0, b1, b2, a1, a2 = coefficients
    z0, z1 = state
    y = [s + b0 * v for s, v in zip(z0, x, strict=True)]
    new = [
        [s + v * b1 - w * a1 for s, v, w in zip(z1, x, y, strict=True)],
        [v * b2 - w * a2 for v, w in zip(x, y, strict=True)],
    ]
    return y, new


def friction_pass(
    base: list[float],
    gaps: list[list[float]],
    stick: list[list[bool]],
    e_kin: list[float],
    e_stat: list[float],
) -> None:
    """Effect A: propagate base tensions through the six link crossings (in place).

    At crossing j the tension beyond the link, ``gaps[k][j]``, sticks while the tension before
    it stays inside ``[T e^{−μw}, T e^{+μw}]`` with ``μ = μ_s`` while stuck (``μ_k`` while
    slipping).  Leaving the band makes it slip: the tension beyond becomes the capstan value
    ``T_before e^{∓μ_k w}`` (the stick–slip jump when breaking away at ``μ_s``).

    Parameters
    ----------
    base : list of 4 float
        Tension entering the robot per tendon.
    gaps : list of 4 lists of 6 float
        Gap tensions, updated in place.
    stick : list of 4 lists of 6 bool
        Stick flags, updated in place.
    e_kin, e_stat : list of 6 float
        ``exp(μ_k w_j)`` and ``exp(μ_s w_j)`` for the current wraps.
    """
    for k in range(4):
        before = base[k]
        row, flags = gaps[k], stick[k]
        for j in range(N_JOINTS):
            beyond = row[j]
            band = e_stat[j] if flags[j] else e_kin[j]
            if before > beyond * band:
                beyond = before / e_kin[j]
                flags[j] = False
            elif before * band < beyond:
                beyond = before * e_kin[j]
                flags[j] = False
            else:
                flags[j] = True
            row[j] = beyond
            before = beyond


def play(values: np.ndarray, start: np.ndarray, half_width: float) -> np.ndarray:
    """Effect B: play operator ``v ← clip(v, x − b, x + b)`` over samples ``(n, m)``."""
    out = np.empty_like(values)
    v = np.array(start, dtype=float)
    lo_all = values - half_width
    hi_all = values + half_width
    for k in range(values.shape[0]):
        np.clip(v, lo_all[k], hi_all[k], out=v)
        out[k] = v
    return out
