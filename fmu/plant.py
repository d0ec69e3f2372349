"""Physics plant of the tendon-driven rolling-joint snake robot (pure numpy; spec plant.md).

The plant advances in frames of ``h`` seconds (30 ms by default) with the exact zero-order-hold
step of spec §9: the linear part of the fast model ``M0 q̈ + C q̇ + k_e q = τ_t + τ_g + τ_x`` is
integrated exactly with a matrix looked up by the total tension, the nonlinear remainder is held
over the frame.  Every hidden effect of spec §10 can be switched on through
:class:`PlantConfig`; the frame order follows spec §13: delay, clip, force loop, dead zone,
friction, table index, remainder, state update, backlash, sensors.

Two ways to drive it, which give identical results:

* :meth:`Plant.step` — one frame, FMU style: apply ``T_cmd`` over ``[t, t + h]`` and return the
  sensors at ``t + h`` (copies, never views of the state);
* :meth:`Plant.run` — a whole input sequence at once, continuing from the current state (the
  effects without feedback into the mechanics are applied vectorised around the frame loop).

:meth:`Plant.record` returns the same data aligned like a logged experiment (row k holds the
command issued at ``t_k`` and the sensors read at ``t_k``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.signal

from tendonkit.errors import DataError, OptionError
from tendonkit.fmu._config import (
    MOUNTS,
    PARAMETER_RANGES,
    PRESETS,
    PlantConfig,
    config_from_dict,
    config_to_dict,
)
from tendonkit.fmu._effects import (
    S_MAX,
    S_MIN,
    friction_pass,
    gravity_vector,
    length_change_scalar,
    play,
    softplus_deadzone,
    softplus_scalar,
    step_table,
    table_index,
    tendon_length_change,
    tendon_torque,
)
from tendonkit.fmu._linear import linearise
from tendonkit.fmu._sensors import SensorModel
from tendonkit.robot import N_JOINTS, N_TENDONS, RobotParameters
from tendonkit.robot.kinematics import scalar_forward_kinematics

__all__ = [
    "MOUNTS",
    "OUTPUT_SIZES",
    "PARAMETER_RANGES",
    "PRESETS",
    "Plant",
    "PlantConfig",
    "config_from_dict",
    "config_to_dict",
    "gravity_vector",
    "linearise",
    "tendon_length_change",
    "tendon_torque",
]

#: Outputs of :meth:`Plant.step` / :meth:`Plant.run` and their widths.  ``q``, ``ee`` and
#: ``T_meas`` are what the sensors report; the rest is truth for test oracles.  ``T_gap`` is
#: tendon-major: entry ``6 k + i`` is tendon k+1 in the gap of joint i+1.
OUTPUT_SIZES: dict[str, int] = {
    "q": 6,
    "ee": 3,
    "T_meas": 4,
    "q_true": 6,
    "qd_true": 6,
    "ee_true": 3,
    "q_vis": 6,
    "T_applied": 4,
    "T_gap": 24,
}


class Plant(SensorModel):
    """The robot simulator: six rolling joints, four tendons and switchable hidden effects.

    Parameters
    ----------
    config : PlantConfig, optional
        Hidden effects; all off (the nominal plant) by default.
    robot : RobotParameters, optional
        Geometry and masses; the nominal robot by default.
    h : float
        Communication step (frame length), s.  The step table is built for this ``h``.
    sensor_period : float
        Sampling period of the camera and the load cells, s (spec §11: 30 ms).  With another
        ``h`` the sensor outputs are sampled at these instants and held in between (the camera
        filter and the noise run at this rate); the truth outputs follow every step.

    Examples
    --------
    >>> plant = Plant()
    >>> out = plant.step([150.0, 105.0, 60.0, 105.0])
    >>> sorted(out)[:3]
    ['T_applied', 'T_gap', 'T_meas']
    >>> y = plant.run(np.tile([150.0, 105.0, 60.0, 105.0], (100, 1)))
    >>> y["q_true"].shape
    (100, 6)
    """

    def __init__(
        self,
        config: PlantConfig | None = None,
        robot: RobotParameters | None = None,
        h: float = 0.03,
        sensor_period: float = 0.03,
    ) -> None:
        self.config = config if config is not None else PlantConfig()
        self.robot = robot if robot is not None else RobotParameters()
        cfg, rob = self.config, self.robot
        problems = []
        for name, value in (("step size h", h), ("sensor_period", sensor_period)):
            if not (
                isinstance(value, int | float) and math.isfinite(value) and 1e-4 <= value <= 0.5
            ):
                problems.append(f"{name} must be in [1e-4, 0.5] s, found {value!r}")
        if not problems and cfg.camera_on and cfg.camera_fc >= 0.45 / sensor_period:
            limit = 0.45 / sensor_period
            problems.append(f"camera_fc ({cfg.camera_fc} Hz) must be below {limit:g} Hz")
        if problems:
            raise OptionError("Invalid plant setup:", problems)
        self.h = float(h)
        self.sensor_period = float(sensor_period)
        self._extra = cfg.hardening_on or cfg.softening_on
        k_t = cfg.forcelag_kt if cfg.forcelag_on else 0.0
        self._mats, _ = step_table(rob, self.h, cfg.mount, float(k_t), self._extra)
        self._adn = np.hstack([-rob.a, rob.d])  # (4, 12): tensions -> [−Σ a T, Σ d T]
        self._l0 = 2.0 * rob.a.sum(axis=1)  # ΔL = l0 − [2d | 2a] @ [sin; cos]
        self._adl = 2.0 * np.hstack([rob.d, rob.a])
        self._k_nom = rob.stiffness()
        if cfg.forcelag_on:  # force loop (effect F): gain, step limit and tendon springs
            k_t = cfg.forcelag_kt
            self._gain = (1.0 - math.exp(-self.h / cfg.forcelag_tau)) / k_t
            self._v_h = cfg.forcelag_vmax * self.h
            self._k_l0, self._k_adl = k_t * self._l0, k_t * self._adl
        if self._extra:  # stiffness effects (K)
            self._k3 = cfg.hardening_k3 * self._k_nom
            self._soft = cfg.softening_s * self._k_nom
        if cfg.friction_on:  # capstan exponents μ (β0 + |q̂_{i−1}|/2 + |q̂_i|/2) of effect A
            self._mus = np.array([[cfg.friction_mu_k], [cfg.friction_mu_s]])
            self._wraps = np.zeros(N_JOINTS + 1)  # [0, |q̂/2|]
        delay = cfg.delay_s if cfg.delay_on else 0.0
        frames = delay / self.h
        self._n_delay = math.floor(frames + 1e-9)
        alpha = frames - self._n_delay
        self._alpha = alpha if alpha > 1e-9 else 0.0
        if cfg.camera_on:
            self._filter = scipy.signal.butter(2, cfg.camera_fc, fs=1.0 / self.sensor_period)
            b, a = self._filter  # normalised by a[0] as scipy.signal.lfilter does
            self._biquad = tuple(float(v) for v in (*(b / a[0]), *(a[1:] / a[0])))
        self._sigma = np.array(
            [cfg.noise_sigma_q] * 6 + [cfg.noise_sigma_p] * 3 + [cfg.noise_sigma_T] * 4
        )
        # Per-frame path (step, FMU): plain floats around three numpy calls per frame.  It
        # needs a sensor sample at every frame end; otherwise step() goes through run().
        self._fk = scalar_forward_kinematics(rob)
        self._lean = self.h >= self.sensor_period
        self._a_rows, self._d_rows = rob.a.tolist(), rob.d.tolist()
        self._top = int(S_MAX - S_MIN)  # last table index
        self.reset()

    # ------------------------------------------------------------------ state handling
    def reset(self, seed: int | None = None) -> dict[str, np.ndarray]:
        """Return to the initial state: straight, at rest, every tension at ``P_nom``.

        Parameters
        ----------
        seed : int, optional
            Noise seed for this run; defaults to ``config.seed``.

        Returns
        -------
        dict
            The sensor outputs at t = 0 (copies).
        """
        rob, cfg = self.robot, self.config
        P = rob.P_nom
        nj = N_JOINTS
        self._frame = 0
        self._rng = np.random.default_rng(cfg.seed if seed is None else seed)
        self._noise_rows: list[list[float]] = []  # drawn, not yet used; the next one is last
        # The table's input vector z of the current frame (spec §9): [x, q̂/2, q̂/2 + π/2,
        # τ_x, 1]; its first 24 entries are the state, the rest is rewritten every frame.
        self._z = np.zeros(self._mats.shape[2])
        self._z[3 * nj : 4 * nj] = 0.5 * np.pi
        self._z[-1] = 1.0
        self._z_new = np.empty(4 * nj)
        self._hold = [P] * N_TENDONS
        t_eff = self._dead_zone(np.full(N_TENDONS, P))
        self._gaps = [[float(t)] * nj for t in t_eff]
        self._stick = [[True] * nj for _ in range(N_TENDONS)]
        self._hist = [[P] * N_TENDONS for _ in range(self._n_delay + 1)]
        self._q_vis = [0.0] * nj
        self._zi: list[list[float]] = []  # camera filter state (set from the first sample)
        if cfg.settle_s > 0:
            n = round(cfg.settle_s / self.h)
            self._mechanics(np.full((n, N_TENDONS), P))
            self._frame = 0
        first = self._sensors(self._truth_now())
        self._last = {k: v[0].tolist() for k, v in first.items()}
        return self.outputs()

    def _truth_now(self) -> dict[str, np.ndarray]:
        """Truth channels of the current state as one-row arrays."""
        q = self._z[None, :N_JOINTS].copy()
        if self.config.forcelag_on:
            k_t = self.config.forcelag_kt
            t_now = np.array(self._hold) + k_t * tendon_length_change(q[0], self.robot)
        else:
            t_now = np.array(self._hist[-1]).clip(self.robot.T_min, self.robot.T_max)
        return {
            "q_true": q,
            "qd_true": self._z[None, N_JOINTS : 2 * N_JOINTS].copy(),
            "q_vis": np.array([self._q_vis]),
            "T_applied": t_now[None, :].copy(),
            "T_meas": t_now[None, :].copy(),
            "T_gap": np.array(self._gaps).reshape(1, -1),
        }

    def outputs(self) -> dict[str, np.ndarray]:
        """Most recent sensor and truth outputs (after the last step, or of the reset state).

        Returns
        -------
        dict
            1-D copies keyed as :data:`OUTPUT_SIZES`.
        """
        return {k: np.array(v) for k, v in self._last.items()}

    @property
    def time(self) -> float:
        """Simulated time since :meth:`reset`, s."""
        return self._frame * self.h

    @property
    def state(self) -> dict[str, np.ndarray]:
        """Copy of the internal state.

        Keys: ``q``, ``qd``, ``T_hold`` (effect F), ``T_gap`` (4, 6) — the gap tensions of the
        last frame —, ``stick`` (4, 6) (effect A), ``q_vis``, the delay FIFO ``u_hist`` and
        ``time``.
        """
        return {
            "q": self._z[:N_JOINTS].copy(),
            "qd": self._z[N_JOINTS : 2 * N_JOINTS].copy(),
            "T_hold": np.array(self._hold),
            "T_gap": np.array(self._last["T_gap"]).reshape(N_TENDONS, N_JOINTS),
            "stick": np.array(self._stick),
            "q_vis": np.array(self._q_vis),
            "u_hist": np.array(self._hist),
            "time": np.array(self.time),
        }

    # ------------------------------------------------------------------ public stepping
    def step(self, T_cmd: np.ndarray | Sequence[float]) -> dict[str, np.ndarray]:
        """Advance one frame with commanded tensions ``T_cmd`` held over the frame.

        Gives exactly what one row of :meth:`run` gives (to the rounding of batched products,
        ~1e-15), on a per-frame path that avoids numpy's per-call overhead where it can.

        Parameters
        ----------
        T_cmd : array_like
            Commanded tensions (T1, T2, T3, T4), N, shape (4,).

        Returns
        -------
        dict
            Outputs at the end of the frame (see :data:`OUTPUT_SIZES`), 1-D copies, and
            ``"t"``, the time at the end of the frame.
        """
        out: dict[str, Any] = {k: np.array(v) for k, v in self._advance(T_cmd).items()}
        out["t"] = np.float64(self.h * self._frame)
        return out

    def run(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """Advance ``len(u)`` frames, continuing from the current state.

        Row k of every returned array equals what the k-th of ``len(u)`` calls to
        :meth:`step` would return: the plant outputs at ``t + (k + 1) h``.

        Parameters
        ----------
        u : array_like
            Commanded tensions, ``(n, 4)``, N.

        Returns
        -------
        dict
            Arrays ``(n, width)`` keyed as :data:`OUTPUT_SIZES`, plus ``"t"`` ``(n,)`` — the
            time at the end of each frame.
        """
        u = self._check_inputs(np.asarray(u, dtype=float))
        if u.shape[0] == 0:
            empty = {k: np.empty((0, w)) for k, w in OUTPUT_SIZES.items()}
            return {**empty, "t": np.empty(0)}
        k0 = self._frame
        raw = self._mechanics(self._delayed(u))
        out = self._sensors(raw, k0)
        out["t"] = self.h * np.arange(k0 + 1, k0 + u.shape[0] + 1)
        self._last = {k: v[-1].tolist() for k, v in out.items() if k != "t"}
        return out

    def record(self, u: np.ndarray) -> dict[str, np.ndarray]:
        """Run ``u`` and return the data aligned like a logged experiment.

        Row k holds ``t_k``, the command ``u[k]`` issued at ``t_k``, the force the load cells
        read once it is applied (``T_meas``: the tension during frame k for the ideal force
        loop; the tension at ``t_k`` with effect F) and every angle/position read at ``t_k``
        (row 0 is the state before the first command).

        Parameters
        ----------
        u : array_like
            Commanded tensions ``(n, 4)``, N.

        Returns
        -------
        dict
            ``"t"`` ``(n,)``, ``"u"`` ``(n, 4)`` and the keys of :data:`OUTPUT_SIZES`.
        """
        u = self._check_inputs(np.asarray(u, dtype=float))
        before = self.outputs()
        k0 = self._frame
        res = self.run(u)
        log: dict[str, np.ndarray] = {"t": self.h * np.arange(k0, k0 + u.shape[0]), "u": u.copy()}
        shift_force = self.config.forcelag_on
        for key, values in res.items():
            if key == "t":
                continue
            if key in ("T_meas", "T_applied") and not shift_force:
                log[key] = values
            else:
                log[key] = np.concatenate([before[key][None, :], values[:-1]], axis=0)
        return log

    # ------------------------------------------------------------------ one frame
    def _advance(self, T_cmd: np.ndarray | Sequence[float]) -> dict[str, list[float]]:
        """Advance one frame; return the outputs as lists (internal: never modify them).

        The per-frame path of :meth:`step` and of the plant FMU's ``doStep``.  It does what
        one row of :meth:`run` does (spec §13 steps 1–10), operation for operation, but on
        plain floats: numpy only for the half-angle sines, the tension products, the table
        step (and the effects' own small vector operations), so a frame costs a handful of
        numpy calls instead of a run's set-up.  When the sensors do not sample at every frame
        end (``h < sensor_period``) it falls back to :meth:`run`.
        """
        cmd = self._command(T_cmd)
        if not self._lean:
            self.run(np.array([cmd]))
            return self._last
        cfg, nj = self.config, N_JOINTS
        # Steps 1–2: delay FIFO (a fractional delay blends two frames), saturation.
        if self._n_delay or self._alpha:
            ext = [*self._hist, cmd]
            applied = ext[1]
            if self._alpha:
                alpha = self._alpha
                applied = [(1.0 - alpha) * c + alpha * p for c, p in zip(applied, ext[0])]
            self._hist = ext[1:]
        else:
            applied = cmd
            self._hist = [cmd]
        lo, hi = self.robot.T_min, self.robot.T_max
        tc = [lo if t < lo else (hi if t > hi else t) for t in applied]
        # Steps 3–9: force loop, dead zone, friction, table index, remainder, state update.
        z, sc = self._z, self._z[2 * nj : 4 * nj]
        if cfg.friction_on or self._extra:
            q_half = self._z[2 * nj : 3 * nj]  # q̂/2, before the in-place sin
            if cfg.friction_on:
                e_kin, e_stat = self._capstan(q_half)
            if self._extra:
                self._extra_torque(q_half, self._z[4 * nj : 5 * nj])
        np.sin(sc, out=sc)  # [sin(q̂/2), cos(q̂/2)]
        if cfg.forcelag_on:
            hold = self._hold
            t_app = self._force_loop(tc, (self._k_l0 - self._k_adl @ sc).tolist(), hold)
        else:
            t_app = tc
        if cfg.deadzone_on:
            t_eff = [softplus_scalar(t, cfg.deadzone_T, cfg.deadzone_w) for t in t_app]
        else:
            t_eff = t_app
        idx = min(max(round(sum(t_eff) - S_MIN), 0), self._top)
        if cfg.friction_on:
            gaps = self._gaps
            friction_pass(t_eff, gaps, self._stick, e_kin, e_stat)
            t_gap = gaps[0] + gaps[1] + gaps[2] + gaps[3]
            w = (np.array([row + row for row in gaps]) * self._adn).sum(axis=0)
        else:
            t_gap = [t for t in t_eff for _ in range(nj)]
            w = np.dot(t_eff, self._adn)
        np.multiply(sc, w, out=sc)
        np.matmul(self._mats[idx], z, out=self._z_new)
        z[: 4 * nj] = self._z_new
        x = self._z_new[: 2 * nj].tolist()
        q_true, qd_true = x[:nj], x[nj:]
        # Step 10: kinematics, backlash, camera filter, noise.
        ee_true = self._fk(q_true)
        if cfg.backlash_on:
            b = cfg.backlash_b
            q_vis = [min(max(v, q - b), q + b) for v, q in zip(self._q_vis, q_true)]
            meas = q_vis + self._fk(q_vis)
        else:
            q_vis = q_true
            meas = q_true + ee_true
        if cfg.forcelag_on:
            k_t = cfg.forcelag_kt
            change = length_change_scalar(q_true, self._a_rows, self._d_rows)
            t_meas = [t + k_t * d for t, d in zip(hold, change)]
        else:
            t_meas = tc
        meas, t_meas = self._sense_row(meas, t_meas)
        self._q_vis = q_vis
        self._frame += 1
        self._last = {
            "q": meas[:nj],
            "ee": meas[nj:],
            "T_meas": t_meas,
            "q_true": q_true,
            "qd_true": qd_true,
            "ee_true": ee_true,
            "q_vis": q_vis,
            "T_applied": t_app,
            "T_gap": t_gap,
        }
        return self._last

    def _command(self, T_cmd: np.ndarray | Sequence[float]) -> list[float]:
        """One frame's commanded tensions as 4 finite floats (else the error of ``run``)."""
        values = T_cmd.tolist() if isinstance(T_cmd, np.ndarray) else T_cmd
        if isinstance(values, list | tuple) and len(values) == N_TENDONS:
            try:
                cmd = [float(v) for v in values]
            except (TypeError, ValueError):
                pass
            else:
                if math.isfinite(sum(cmd)):
                    return cmd
        u = self._check_inputs(np.asarray(T_cmd, dtype=float).reshape(1, -1))
        return list(u[0].tolist())

    def _force_loop(self, cmd: list[float], dl: list[float], hold: list[float]) -> list[float]:
        """Effect F for one frame: move the carriages (``hold``, in place); return T_applied.

        ``dl`` is the tendon-spring term ``k_t (L(q̂) − L(0))`` at the frame's evaluation point.
        """
        gain, v_h, k_t = self._gain, self._v_h, self.config.forcelag_kt
        t_app = [0.0] * N_TENDONS
        for j in range(N_TENDONS):
            move = (cmd[j] - hold[j] - dl[j]) * gain
            move = v_h if move > v_h else (-v_h if move < -v_h else move)
            hold[j] += k_t * move
            t_app[j] = hold[j] + dl[j]
        return t_app

    def _capstan(self, q_half: np.ndarray) -> list[list[float]]:
        """Effect A: ``[exp(μ_k w_j), exp(μ_s w_j)]`` for the wraps at the half angles q̂/2."""
        wraps = self._wraps
        np.abs(q_half, out=wraps[1:])
        beta0 = self.config.friction_beta0
        e: list[list[float]] = np.exp(self._mus * (beta0 + (wraps[:-1] + wraps[1:]))).tolist()
        return e

    def _extra_torque(self, q_half: np.ndarray, tau: np.ndarray) -> None:
        """Effect K: write the held stiffness torque τ_x(q̂) into ``tau``."""
        cfg = self.config
        q = 2.0 * q_half
        tau[:] = 0.0
        if cfg.hardening_on:
            tau -= self._k3 * q**3
        if cfg.softening_on:
            q_s = cfg.softening_qs
            tau += self._soft * (q - q_s * np.tanh(q / q_s))

    # ------------------------------------------------------------------ internals
    def _check_inputs(self, u: np.ndarray) -> np.ndarray:
        if u.ndim != 2 or u.shape[1] != N_TENDONS:
            raise DataError(f"Tension commands must have shape (n, 4); found {u.shape}.")
        if not np.all(np.isfinite(u)):
            bad = int(np.argmax(~np.all(np.isfinite(u), axis=1)))
            raise DataError(f"Tension commands must be finite; row {bad} is {u[bad].tolist()}.")
        return u

    def _dead_zone(self, tension: np.ndarray) -> np.ndarray:
        cfg = self.config
        if not cfg.deadzone_on:
            return tension
        return softplus_deadzone(tension, cfg.deadzone_T, cfg.deadzone_w)

    def _delayed(self, u: np.ndarray) -> np.ndarray:
        """Steps 1–2: frame FIFO with fractional delay, then saturation."""
        if self._n_delay or self._alpha:
            width = self._n_delay + 1
            ext = np.concatenate([np.array(self._hist), u], axis=0)
            n = u.shape[0]
            cur = ext[width - self._n_delay : width - self._n_delay + n]
            applied = (
                cur
                if not self._alpha
                else (
                    (1.0 - self._alpha) * cur + self._alpha * ext[width - self._n_delay - 1 :][:n]
                )
            )
            self._hist = ext[-width:].tolist()
        else:
            applied = u
            self._hist = u[-1:].tolist()
        return np.clip(applied, self.robot.T_min, self.robot.T_max)

    def _mechanics(self, tc: np.ndarray) -> dict[str, np.ndarray]:
        """Steps 3–9 for every frame: force loop, dead zone, friction, table step, backlash.

        Row k of the work array ``zs`` is the table's input vector z of frame k (spec §9):
        the table writes ``[x⁺, q̂⁺/2, q̂⁺/2 + π/2]`` into row k + 1, whose half-angle part is then
        turned in place into the sin/cos products of the next frame.
        """
        cfg, rob = self.config, self.robot
        n, nj = tc.shape[0], N_JOINTS
        mats = self._mats
        zs = np.zeros((n + 1, mats.shape[2]))
        zs[:, -1] = 1.0
        zs[0, : 4 * nj] = self._z[: 4 * nj]
        heads = zs[:, : 4 * nj]  # where the table writes
        prods = zs[:, 2 * nj : 4 * nj]  # half angles -> sin/cos -> products with tensions
        force, fric, extra = cfg.forcelag_on, cfg.friction_on, self._extra
        dead = cfg.deadzone_on
        top = self._top
        if force:
            k_t = cfg.forcelag_kt
            k_l0, k_adl = self._k_l0, self._k_adl
            hold = self._hold
            t_cmd = tc.tolist()
            t_app_l, hold_l = [], []
            dz_t, dz_w = cfg.deadzone_T, cfg.deadzone_w
        else:
            t_eff_all = self._dead_zone(tc)
            idx_all = table_index(t_eff_all.sum(axis=1)).tolist()
            if not fric:
                w_all = t_eff_all @ self._adn
        if fric:
            gaps, stick = self._gaps, self._stick
            gap_hist = []
            adn = self._adn
        if extra:
            taus = zs[:, 4 * nj : 5 * nj]
        for k in range(n):
            sc = prods[k]
            if fric or extra:
                q_half = zs[k, 2 * nj : 3 * nj]  # q̂/2, before the in-place sin
                if fric:
                    e = self._capstan(q_half)
                if extra:
                    self._extra_torque(q_half, taus[k])
            np.sin(sc, out=sc)  # [sin(q̂/2), cos(q̂/2)]
            if force:
                ta = self._force_loop(t_cmd[k], (k_l0 - k_adl @ sc).tolist(), hold)
                hold_l.append(hold[:])
                t_app_l.append(ta)
                te = [softplus_scalar(t, dz_t, dz_w) for t in ta] if dead else ta
                idx = min(max(round(sum(te) - S_MIN), 0), top)
            else:
                idx = idx_all[k]
                if fric:
                    te = t_eff_all[k].tolist()
            if fric:
                friction_pass(te, gaps, stick, e[0], e[1])
                g = np.array(gaps)
                gap_hist.append(g.ravel())
                w = (np.concatenate((g, g), axis=1) * adn).sum(axis=0)
            elif force:
                w = np.dot(te, self._adn)
            else:
                w = w_all[k]
            np.multiply(sc, w, out=sc)
            np.matmul(mats[idx], zs[k], out=heads[k + 1])
        self._z[: 4 * nj] = zs[n, : 4 * nj]
        hist = zs[1:, : 2 * nj]
        q_true = hist[:, :nj]
        if force:
            t_app = np.array(t_app_l).reshape(n, N_TENDONS)
            t_meas = np.array(hold_l).reshape(n, N_TENDONS) + k_t * tendon_length_change(
                q_true, rob
            )
        else:
            t_app = tc
            t_meas = tc
        if fric:
            t_gap = np.array(gap_hist).reshape(n, N_TENDONS * nj)
        else:
            t_gap = np.repeat(self._dead_zone(t_app), nj, axis=1)
        if cfg.backlash_on:
            q_vis = play(q_true, np.array(self._q_vis), cfg.backlash_b)
        else:
            q_vis = q_true
        if n:
            self._q_vis = q_vis[-1].tolist()
        self._frame += n
        return {
            "q_true": q_true,
            "qd_true": hist[:, nj:],
            "q_vis": q_vis,
            "T_applied": np.array(t_app, copy=True),
            "T_meas": t_meas,
            "T_gap": t_gap,
        }
