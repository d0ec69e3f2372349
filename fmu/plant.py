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

import numpy as np
import scipy.signal

from tendonkit.errors import DataError, OptionError
from tendonkit.fmu._config import (
    MOUNTS,
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
    play,
    softplus_deadzone,
    step_table,
    table_index,
    tendon_length_change,
    tendon_torque,
)
from tendonkit.fmu._effects import coupling_stiffness as _coupling_stiffness
from tendonkit.fmu._effects import gravity_linearisation as _gravity_linearisation
from tendonkit.kinematics import forward_kinematics
from tendonkit.robot import N_JOINTS, N_TENDONS, RobotParameters

__all__ = [
    "MOUNTS",
    "OUTPUT_SIZES",
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
    m_inv = np.linalg.inv(robot.M0)
    a = np.zeros((2 * N_JOINTS, 2 * N_JOINTS))
    a[:N_JOINTS, N_JOINTS:] = np.eye(N_JOINTS)
    a[N_JOINTS:, :N_JOINTS] = -m_inv @ stiff
    a[N_JOINTS:, N_JOINTS:] = -m_inv * robot.damping[None, :]
    b = np.zeros((2 * N_JOINTS, N_TENDONS))
    b[N_JOINTS:] = m_inv @ robot.d.T
    return a, b


def _softplus(tension: float, threshold: float, width: float) -> float:
    """Scalar :func:`softplus_deadzone` for the frame loop."""
    x = (tension - threshold) / width
    return width * (x + math.log1p(math.exp(-x)) if x > 0 else math.log1p(math.exp(x)))


class Plant:
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
        delay = cfg.delay_s if cfg.delay_on else 0.0
        frames = delay / self.h
        self._n_delay = math.floor(frames + 1e-9)
        alpha = frames - self._n_delay
        self._alpha = alpha if alpha > 1e-9 else 0.0
        if cfg.camera_on:
            self._filter = scipy.signal.butter(2, cfg.camera_fc, fs=1.0 / self.sensor_period)
        self._sigma = np.array(
            [cfg.noise_sigma_q] * 6 + [cfg.noise_sigma_p] * 3 + [cfg.noise_sigma_T] * 4
        )
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
        self._frame = 0
        self._rng = np.random.default_rng(cfg.seed if seed is None else seed)
        self._out = np.zeros(4 * N_JOINTS)
        self._out[3 * N_JOINTS :] = 0.5 * np.pi
        self._hold = np.full(N_TENDONS, P)
        t_eff = self._dead_zone(np.full(N_TENDONS, P))
        self._gaps = [[float(t)] * N_JOINTS for t in t_eff]
        self._stick = [[True] * N_JOINTS for _ in range(N_TENDONS)]
        self._hist = np.full((self._n_delay + 1, N_TENDONS), P)
        self._q_vis = np.zeros(N_JOINTS)
        self._zi: np.ndarray | None = None
        if cfg.settle_s > 0:
            n = round(cfg.settle_s / self.h)
            self._mechanics(np.full((n, N_TENDONS), P))
            self._frame = 0
        current = self._truth_now()
        self._last = self._sensors(current)
        return self.outputs()

    def _truth_now(self) -> dict[str, np.ndarray]:
        """Truth channels of the current state as one-row arrays."""
        q = self._out[None, :N_JOINTS].copy()
        if self.config.forcelag_on:
            k_t = self.config.forcelag_kt
            t_now = self._hold + k_t * tendon_length_change(q[0], self.robot)
        else:
            t_now = self._hist[-1].clip(self.robot.T_min, self.robot.T_max)
        return {
            "q_true": q,
            "qd_true": self._out[None, N_JOINTS : 2 * N_JOINTS].copy(),
            "q_vis": self._q_vis[None, :].copy(),
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
        return {k: v[0].copy() for k, v in self._last.items()}

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
            "q": self._out[:N_JOINTS].copy(),
            "qd": self._out[N_JOINTS : 2 * N_JOINTS].copy(),
            "T_hold": self._hold.copy(),
            "T_gap": self._last["T_gap"].reshape(N_TENDONS, N_JOINTS).copy(),
            "stick": np.array(self._stick),
            "q_vis": self._q_vis.copy(),
            "u_hist": self._hist.copy(),
            "time": np.array(self.time),
        }

    # ------------------------------------------------------------------ public stepping
    def step(self, T_cmd: np.ndarray | list[float]) -> dict[str, np.ndarray]:
        """Advance one frame with commanded tensions ``T_cmd`` held over the frame.

        Parameters
        ----------
        T_cmd : array_like
            Commanded tensions (T1, T2, T3, T4), N, shape (4,).

        Returns
        -------
        dict
            Outputs at the end of the frame (see :data:`OUTPUT_SIZES`), 1-D copies.
        """
        u = self._check_inputs(np.asarray(T_cmd, dtype=float).reshape(1, -1))
        res = self.run(u)
        return {k: v[0] for k, v in res.items()}

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
        self._last = {k: v[-1:].copy() for k, v in out.items() if k != "t"}
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
            ext = np.concatenate([self._hist, u], axis=0)
            n = u.shape[0]
            cur = ext[width - self._n_delay : width - self._n_delay + n]
            applied = (
                cur
                if not self._alpha
                else (
                    (1.0 - self._alpha) * cur + self._alpha * ext[width - self._n_delay - 1 :][:n]
                )
            )
            self._hist = ext[-width:].copy()
        else:
            applied = u
            self._hist = u[-1:].copy()
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
        zs[0, : 4 * nj] = self._out
        heads = zs[:, : 4 * nj]  # where the table writes
        prods = zs[:, 2 * nj : 4 * nj]  # half angles -> sin/cos -> products with tensions
        force, fric, extra = cfg.forcelag_on, cfg.friction_on, self._extra
        dead = cfg.deadzone_on
        top = int(S_MAX - S_MIN)
        if force:
            k_t = cfg.forcelag_kt
            gain = (1.0 - math.exp(-self.h / cfg.forcelag_tau)) / k_t
            v_h = cfg.forcelag_vmax * self.h
            k_l0, k_adl = k_t * self._l0, k_t * self._adl
            hold = self._hold.tolist()
            t_cmd = tc.tolist()
            t_app_l, hold_l = [], []
            dz_t, dz_w = cfg.deadzone_T, cfg.deadzone_w
        else:
            t_eff_all = self._dead_zone(tc)
            idx_all = table_index(t_eff_all.sum(axis=1)).tolist()
            if not fric:
                w_all = t_eff_all @ self._adn
        if fric:
            mus = np.array([[cfg.friction_mu_k], [cfg.friction_mu_s]])
            beta0 = cfg.friction_beta0
            gaps, stick = self._gaps, self._stick
            gap_hist = []
            qa = np.zeros(nj + 1)
            qa_tail = qa[1:]
            adn = self._adn
        if extra:
            k3 = cfg.hardening_k3 * self._k_nom if cfg.hardening_on else None
            soft = cfg.softening_s * self._k_nom if cfg.softening_on else None
            q_s = cfg.softening_qs
            taus = zs[:, 4 * nj : 5 * nj]
        for k in range(n):
            sc = prods[k]
            if fric or extra:
                q_half = zs[k, 2 * nj : 3 * nj]  # q̂/2, before the in-place sin
                if fric:
                    np.abs(q_half, out=qa_tail)
                    e = np.exp(mus * (beta0 + (qa[:-1] + qa_tail))).tolist()
                if extra:
                    q = 2.0 * q_half
                    tau = taus[k]
                    if k3 is not None:
                        tau -= k3 * q**3
                    if soft is not None:
                        tau += soft * (q - q_s * np.tanh(q / q_s))
            np.sin(sc, out=sc)  # [sin(q̂/2), cos(q̂/2)]
            if force:
                dl = (k_l0 - k_adl @ sc).tolist()
                cmd = t_cmd[k]
                ta = [0.0] * 4
                for j in range(4):
                    move = (cmd[j] - hold[j] - dl[j]) * gain
                    move = v_h if move > v_h else (-v_h if move < -v_h else move)
                    hold[j] += k_t * move
                    ta[j] = hold[j] + dl[j]
                hold_l.append(hold[:])
                t_app_l.append(ta)
                te = [_softplus(t, dz_t, dz_w) for t in ta] if dead else ta
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
        self._out = zs[n, : 4 * nj].copy()
        hist = zs[1:, : 2 * nj]
        q_true = hist[:, :nj]
        if force:
            self._hold = np.array(hold)
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
            q_vis = play(q_true, self._q_vis, cfg.backlash_b)
        else:
            q_vis = q_true
        if n:
            self._q_vis = q_vis[-1].copy()
        self._frame += n
        return {
            "q_true": q_true,
            "qd_true": hist[:, nj:],
            "q_vis": q_vis,
            "T_applied": np.array(t_app, copy=True),
            "T_meas": t_meas,
            "T_gap": t_gap,
        }

    def _sample_mask(self, k0: int, n: int) -> np.ndarray:
        """Which of the step ends k0+1 … k0+n carry a new sensor sample (every ``sensor_period``)."""
        ends = np.arange(k0, k0 + n + 1) * (self.h / self.sensor_period)
        count = np.floor(ends + 1e-9)
        return count[1:] > count[:-1]

    def _sensors(self, raw: dict[str, np.ndarray], k0: int | None = None) -> dict[str, np.ndarray]:
        """Step 10: end-effector kinematics, camera filter, noise, sample-and-hold.

        ``k0`` is the frame before the first row; ``None`` marks the initial sample at reset.
        """
        cfg = self.config
        ee_true = forward_kinematics(raw["q_true"], self.robot)
        ee_vis = forward_kinematics(raw["q_vis"], self.robot) if cfg.backlash_on else ee_true
        meas = np.concatenate([raw["q_vis"], ee_vis], axis=1)
        t_meas = raw["T_meas"]
        n = meas.shape[0]
        mask = np.ones(n, dtype=bool) if k0 is None else self._sample_mask(k0, n)
        held = not mask.all()
        if held:
            meas, t_meas = meas[mask], t_meas[mask]
        if cfg.camera_on and meas.shape[0]:
            b, a = self._filter
            if k0 is None:  # the filter starts in steady state at the initial value
                self._zi = scipy.signal.lfilter_zi(b, a)[:, None] * meas[0][None, :]
            else:
                meas, self._zi = scipy.signal.lfilter(b, a, meas, axis=0, zi=self._zi)
        if cfg.noise_on and meas.shape[0]:
            noise = self._rng.standard_normal((meas.shape[0], 13)) * self._sigma
            meas = meas + noise[:, :9]
            t_meas = t_meas + noise[:, 9:]
            if cfg.noise_quantum_T > 0:
                t_meas = np.round(t_meas / cfg.noise_quantum_T) * cfg.noise_quantum_T
        if held:  # hold the previous sample between sensor instants
            last = self._last
            prev = np.concatenate([last["q"], last["ee"]], axis=1)
            meas = np.concatenate([prev, meas])[np.cumsum(mask)]
            t_meas = np.concatenate([last["T_meas"], t_meas])[np.cumsum(mask)]
        return {
            "q": np.array(meas[:, :N_JOINTS]),
            "ee": np.array(meas[:, N_JOINTS:]),
            "T_meas": np.array(t_meas, copy=True),
            "q_true": np.array(raw["q_true"], copy=True),
            "qd_true": np.array(raw["qd_true"], copy=True),
            "ee_true": ee_true,
            "q_vis": np.array(raw["q_vis"], copy=True),
            "T_applied": raw["T_applied"],
            "T_gap": np.array(raw["T_gap"], copy=True),
        }
