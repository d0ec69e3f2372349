"""diagnose on a two-input, two-output system with the effect on one channel only.

Two coupled mass-spring-dampers (modes near 0.8 and 1.7 Hz; inputs `fa`, `fb`, outputs `xa`,
`xb`; input `fa` also pushes the second mass), driven by independent band-limited random
forces (rms 10) and measured with 2 % white output noise, simulated with RK4 at 10 sub-steps
per 50 ms sample.  The effect acts on the first input or the first mass only, as one worn
actuator or one rubbing joint among several would.  The baseline is diagnose's default
(ARX(8, 8, 1)).  An effect on one input is found by the one-input-at-a-time step of the
input effects (before it, an input clip on both inputs gained +0.74 points, p_adj 0.01, and
the plant was called ``none``).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from tendonkit.dataset import Dataset, Experiment
from tendonkit.diagnose import diagnose

pytestmark = pytest.mark.slow

DT = 0.05
M = np.diag([1.0, 0.5])
K = np.array([[30.0, -8.0], [-8.0, 60.0]])
C = np.diag([0.5, 0.4])
B = np.array([[1.0, 0.3], [0.0, 1.0]])


def _forces(n: int, seed: int) -> np.ndarray:
    noise = np.random.default_rng(seed).standard_normal((n, 2))
    u = lfilter(*butter(2, 2.0, fs=1.0 / DT), noise, axis=0)
    return 10.0 * u / u.std(axis=0)


def _response(u: np.ndarray, effect: str, sub: int = 10) -> np.ndarray:
    u = u.copy()
    if effect == "dead_zone":
        u[:, 0] = np.sign(u[:, 0]) * np.maximum(np.abs(u[:, 0]) - 3.0, 0.0)
    elif effect == "saturation":
        u[:, 0] = np.clip(u[:, 0], -12.0, 12.0)
    elif effect == "actuator_lag":
        a = np.exp(-DT / 0.15)
        u[:, 0] = lfilter([0.0, 1.0 - a], [1.0, -a], u[:, 0])
    minv = np.linalg.inv(M)

    def acc(x: np.ndarray, v: np.ndarray, f: np.ndarray) -> np.ndarray:
        force = B @ f - C @ v - K @ x
        if effect == "coulomb_friction":
            force[0] -= 1.2 * np.tanh(v[0] / 1e-3)
        return minv @ force

    h = DT / sub
    x, v = np.zeros(2), np.zeros(2)
    y = np.empty((len(u), 2))
    for i, f in enumerate(u):
        y[i] = x
        for _ in range(sub):
            k1x, k1v = v, acc(x, v, f)
            k2x, k2v = v + h / 2 * k1v, acc(x + h / 2 * k1x, v + h / 2 * k1v, f)
            k3x, k3v = v + h / 2 * k2v, acc(x + h / 2 * k2x, v + h / 2 * k2v, f)
            k4x, k4v = v + h * k3v, acc(x + h * k3x, v + h * k3v, f)
            x = x + h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
            v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return y


def _data(effect: str, seed: int, n: int = 3000) -> Dataset:
    exps = []
    for i in range(2):
        u = _forces(n, 10 * seed + i)
        y = _response(u, effect)
        rng = np.random.default_rng(10 * seed + i + 5)
        y = y + 0.02 * y.std(axis=0) * rng.standard_normal(y.shape)
        exps.append(Experiment(t=DT * np.arange(n), u=u, y=y, name=f"r{i}"))
    return Dataset(inputs=("fa", "fb"), outputs=("xa", "xb"), experiments=tuple(exps), dt=DT)


@pytest.mark.parametrize(
    "effect", ["none", "coulomb_friction", "dead_zone", "saturation", "actuator_lag"]
)
def test_an_effect_on_one_channel_is_named(effect):
    d = diagnose(_data(effect, 1), _data(effect, 2))
    top = ", ".join(f"{f.effect} {f.gain:+.2f} (p_adj {f.p_adjusted:.1e})" for f in d.findings[:3])
    print(f"{effect}: cause {d.cause} via {d.baseline_method}; {top}")
    assert d.cause == effect, top
    if effect != "none":
        assert d.best is not None and d.best.gain > 0
    if effect == "saturation":
        # the one-input-at-a-time step puts the clip on the input that has it
        assert d.best.params["inputs"] == ["fa"], d.best.params
