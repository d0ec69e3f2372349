"""The plant's sensors (spec §11, frame step 10): camera filter, noise, sample-and-hold.

A mixin of :class:`tendonkit.fmu.plant.Plant`, split from it to keep one concept per module.
It reads the plant's configuration, robot, random generator and filter state, and writes the
filter state and the cached noise rows.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.signal

from tendonkit.fmu._effects import biquad_step
from tendonkit.robot import N_JOINTS
from tendonkit.robot.kinematics import forward_kinematics

#: Sensor-noise rows are drawn in blocks of this many frames (one generator call per block).
_NOISE_BLOCK = 64


class SensorModel:
    """End-effector kinematics, camera low-pass, sensor noise and sample-and-hold."""

    # provided by the plant
    config: Any
    robot: Any
    h: float
    sensor_period: float
    _rng: np.random.Generator
    _sigma: np.ndarray
    _noise_rows: list[list[float]]
    _filter: Any
    _biquad: Any
    _zi: list[list[float]]
    _last: dict[str, list[float]]

    def _sense_row(self, meas: list[float], t_meas: list[float]) -> tuple[list[float], list[float]]:
        """One frame of the camera filter and the sensor noise, on plain floats."""
        cfg = self.config
        if cfg.camera_on:
            meas, self._zi = biquad_step(meas, self._zi, self._biquad)
        if cfg.noise_on:
            noise = self._noise_row()
            meas = [m + e for m, e in zip(meas, noise)]
            t_meas = [t + e for t, e in zip(t_meas, noise[9:])]
            quantum = cfg.noise_quantum_T
            if quantum > 0:
                t_meas = [round(t / quantum) * quantum for t in t_meas]
        return meas, t_meas

    def _noise_row(self) -> list[float]:
        """The next row of scaled sensor noise; rows are drawn in blocks of :data:`_NOISE_BLOCK`."""
        rows = self._noise_rows
        if not rows:
            rows[:] = (self._rng.standard_normal((_NOISE_BLOCK, 13)) * self._sigma).tolist()
            rows.reverse()
        return rows.pop()

    def _noise(self, n: int) -> np.ndarray:
        """The next ``n`` rows of scaled sensor noise, ``(n, 13)``: the same stream as rows."""
        rows = self._noise_rows
        take = min(n, len(rows))
        cached = rows[len(rows) - take :][::-1]
        del rows[len(rows) - take :]
        fresh = self._rng.standard_normal((n - take, 13)) * self._sigma
        if not take:
            return fresh
        return np.concatenate([np.array(cached).reshape(take, 13), fresh])

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
                zi = scipy.signal.lfilter_zi(b, a)[:, None] * meas[0][None, :]
            else:
                meas, zi = scipy.signal.lfilter(b, a, meas, axis=0, zi=np.array(self._zi))
            self._zi = zi.tolist()
        if cfg.noise_on and meas.shape[0]:
            noise = self._noise(meas.shape[0])
            meas = meas + noise[:, :9]
            t_meas = t_meas + noise[:, 9:]
            if cfg.noise_quantum_T > 0:
                t_meas = np.round(t_meas / cfg.noise_quantum_T) * cfg.noise_quantum_T
        if held:  # hold the previous sample between sensor instants
            last = self._last
            prev = np.array([last["q"] + last["ee"]])
            meas = np.concatenate([prev, meas])[np.cumsum(mask)]
            t_meas = np.concatenate([np.array([last["T_meas"]]), t_meas])[np.cumsum(mask)]
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
