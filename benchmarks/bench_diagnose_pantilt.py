"""diagnose at default options on a two-axis tendon joint written outside this repository.

The plant and its effects were written by an independent tester (a probe, 2026-11-28) who did
not read the effects' code; they are kept here as written, apart from the layout.  A pan/tilt
pair of revolute joints with mild inertial and elastic coupling, each driven by an
antagonistic pair of tendons through a pulley (``tau1 = r1 (T1 - T2)``, ``tau2 = r2 (T3 -
T4)``), the four commanded tensions (pretension 75 N; band-limited noise, random held levels
and two logarithmic sine sweeps per axis) as inputs, the two joint angles as outputs with 2 %
white noise, sampled at 20 ms and integrated by RK4 at 0.25 ms; a 10 s run-in is discarded,
so every record starts with the plant moving.  Training 240 s, validation 150 s (another
excitation seed).  The nominal parameters are drawn ±10 % from the case's seed.

One hidden effect per case, its magnitude drawn from the seed:

- ``input_delay``: 3–12 samples on the four commands (a signal that was running before);
- ``coulomb_friction``: ``Fc tanh(q'/0.01)`` at both joints, Fc 0.06–0.15 N·m (against the
  joints' springs: a joint that sticks);
- ``backlash``: a play of total width 0.03–0.08 rad between a spring-loaded drive pulley (40 %
  of the inertia) and the measured link;
- ``actuator_lag``: each tension actuator a first-order lag of 0.05–0.12 s with a slew limit of
  100–200 N/s;
- ``saturation``: the delivered tension limited at 100–112 N;
- ``dead_zone``: a slack tendon delivers ``max(T - Ts, 0)``, Ts 45–58 N;
- ``hysteresis``: a Bouc–Wen element in each joint spring (share alpha 0.3–0.5, z0 0.12–0.25);
- ``nonlinear_stiffness``: hardening springs ``k q + k3 q^3``, k3/k 0.8–2;
- ``gravity``: the tilt joint carries ``m g l sin(q2 + phi0)``, mgl 0.4–0.8 N·m, phi0 0.5–1.2;
- ``none``: the nominal plant.

A case is right when the first cause named is the hidden effect (``none``: nothing named).
The data are rounded as the probe's CSV files were (tensions to 1e-4 N, angles to 1e-6 rad),
so that the command-line runs of the probe and this script see the same numbers.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_diagnose_pantilt.py \
        --jobs 2 --out results.json
"""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np
from bench_diagnose_chain import result_row, run_cases
from numba import njit
from scipy import signal

from tendonkit.dataset import Dataset, Experiment

DT = 0.02
SUB = 80  # sub-steps per sample -> 0.25 ms
RUNIN = 10.0

EFFECTS = [
    "none",
    "input_delay",
    "coulomb_friction",
    "backlash",
    "actuator_lag",
    "saturation",
    "dead_zone",
    "hysteresis",
    "nonlinear_stiffness",
    "gravity",
]
CODE = {e: i for i, e in enumerate(EFFECTS)}


def nominal_params(rng):
    f = lambda: 1.0 + 0.1 * (2 * rng.random() - 1)  # noqa: E731
    J1, J2 = 0.008 * f(), 0.005 * f()
    k1, k2 = 1.5 * f(), 1.2 * f()
    zeta = 0.25 * f()
    return dict(
        J1=J1,
        J2=J2,
        J12=0.08 * math.sqrt(J1 * J2),
        k1=k1,
        k2=k2,
        k12=0.15 * math.sqrt(k1 * k2),
        b1=2 * zeta * math.sqrt(k1 * J1),
        b2=2 * zeta * math.sqrt(k2 * J2),
        r1=0.015 * f(),
        r2=0.015 * f(),
    )


def effect_params(effect, rng, nom):
    u = lambda a, b: float(a + (b - a) * rng.random())  # noqa: E731
    if effect == "none":
        return {}
    if effect == "input_delay":
        return {"delay_samples": int(rng.integers(3, 13))}
    if effect == "coulomb_friction":
        return {"Fc": u(0.06, 0.15), "eps": 0.01}
    if effect == "backlash":
        # v2: play between the spring-loaded drive pulley (40 % of the inertia) and the link
        return {"play_total_rad": u(0.03, 0.08), "link_fraction": 0.6, "kg": 400.0, "cg": 1.0}
    if effect == "actuator_lag":
        # v2: slew limit low enough to bind (v1's 300-600 N/s never bound: a purely linear lag)
        return {"tau": u(0.05, 0.12), "rate": u(100.0, 200.0)}
    if effect == "saturation":
        return {"Tmax": u(100.0, 112.0)}
    if effect == "dead_zone":
        return {"Ts": u(45.0, 58.0)}
    if effect == "hysteresis":
        return {"alpha": u(0.3, 0.5), "z0": u(0.12, 0.25)}
    if effect == "nonlinear_stiffness":
        return {"k3_over_k": u(0.8, 2.0)}
    if effect == "gravity":
        return {"mgl": u(0.4, 0.8), "phi0": u(0.5, 1.2)}
    raise ValueError(effect)


# ---------------------------------------------------------------- excitation
def excitation(seed, duration):
    """Commanded tensions (N, ZOH per sample) for duration + RUNIN seconds."""
    rng = np.random.default_rng(seed)
    n = round((duration + RUNIN) / DT)
    t = np.arange(n) * DT
    b, a = signal.butter(2, 3.0 / (0.5 / DT))
    bc, ac = signal.butter(1, 0.3 / (0.5 / DT))
    T0 = 75.0
    out = np.zeros((n, 4))
    for j in range(2):
        noise = signal.lfilter(b, a, rng.standard_normal(n))
        noise *= 14.0 / noise.std()
        # random held levels (hold 0.4-3 s)
        steps = np.zeros(n)
        i = 0
        while i < n:
            h = int(rng.uniform(0.4, 3.0) / DT)
            steps[i : i + h] = rng.uniform(-25, 25)
            i += h
        d = noise + 0.6 * steps
        # two sine sweeps of 25 s per axis (0.05 -> 4 Hz), placed at random
        for _ in range(2):
            L = int(25.0 / DT)
            s0 = int(rng.integers(int(RUNIN / DT), n - L))
            tt = np.arange(L) * DT
            sw = 22.0 * signal.chirp(tt, 0.05, tt[-1], 4.0, method="logarithmic")
            win = np.minimum(1.0, np.minimum(tt, tt[-1] - tt) / 1.0)
            d[s0 : s0 + L] = (1 - win) * d[s0 : s0 + L] + win * sw
        c = signal.lfilter(bc, ac, rng.standard_normal(n))
        c *= 6.0 / c.std()
        d = np.clip(d, -52, 52)
        out[:, 2 * j] = T0 + c + d
        out[:, 2 * j + 1] = T0 + c - d
    return t, np.clip(out, 5.0, None)


# ---------------------------------------------------------------- dynamics
@njit(cache=False)
def _tension(u, x, code, p):
    # u: the four commanded tensions (held); x: state; returns delivered tensions
    T = np.empty(4)
    for j in range(4):
        Tj = u[j]
        if code == 4:  # actuator_lag: state x[10+j]
            Tj = x[10 + j]
        if code == 5:
            Tj = min(Tj, p[0])
        if code == 6:
            Tj = max(Tj - p[0], 0.0)
        T[j] = Tj
    return T


@njit(cache=False)
def _rhs(x, u, code, p, nm):
    # nm: J1, J2, J12, k1, k2, k12, b1, b2, r1, r2
    J1, J2, J12, k1, k2, k12, b1, b2, r1, r2 = (
        nm[0],
        nm[1],
        nm[2],
        nm[3],
        nm[4],
        nm[5],
        nm[6],
        nm[7],
        nm[8],
        nm[9],
    )
    dx = np.zeros(14)
    q1, w1, q2, w2 = x[0], x[1], x[2], x[3]
    T = _tension(u, x, code, p)
    tau1 = r1 * (T[0] - T[1])
    tau2 = r2 * (T[2] - T[3])
    # joint restoring torques
    s1 = k1 * q1 + k12 * q2
    s2 = k2 * q2 + k12 * q1
    if code == 7:  # hysteresis: Bouc-Wen share of each joint spring
        alpha = p[0]
        s1 = k1 * (alpha * q1 + (1 - alpha) * x[8]) + k12 * q2
        s2 = k2 * (alpha * q2 + (1 - alpha) * x[9]) + k12 * q1
        z0 = p[1]
        for i in range(2):
            w = x[2 * i + 1]
            z = x[8 + i]
            sg = 1.0 if w * z > 0 else -1.0
            dx[8 + i] = w * (1.0 - (0.5 * sg + 0.5) * abs(z) / z0)
    if code == 8:
        s1 += p[0] * k1 * q1**3
        s2 += p[0] * k2 * q2**3
    f1 = b1 * w1 + s1
    f2 = b2 * w2 + s2
    if code == 2:
        f1 += p[0] * math.tanh(w1 / p[1])
        f2 += p[0] * math.tanh(w2 / p[1])
    if code == 9:
        f2 += p[0] * math.sin(q2 + p[1])
    if code == 3:  # backlash (v2): drive pulley with the joint spring, play, then the link
        # pulley i: Jp_i p'' = tau_i - k_i p_i - bp_i p' - tc_i ; link: fl*M q'' = tc - bl q' - coupling
        half, fl, kg, cg = p[0], p[1], p[2], p[3]
        tc = np.zeros(2)
        for i in range(2):
            pa, pv = x[4 + 2 * i], x[5 + 2 * i]
            qa, qv = x[2 * i], x[2 * i + 1]
            e = pa - qa
            if e > half:
                tc[i] = kg * (e - half) + cg * (pv - qv)
            elif e < -half:
                tc[i] = kg * (e + half) + cg * (pv - qv)
        Jp1, Jp2 = (1 - fl) * J1, (1 - fl) * J2
        dx[4] = x[5]
        dx[5] = (tau1 - k1 * x[4] - 0.3 * b1 * x[5] - tc[0]) / Jp1
        dx[6] = x[7]
        dx[7] = (tau2 - k2 * x[6] - 0.3 * b2 * x[7] - tc[1]) / Jp2
        a1 = tc[0] - 0.7 * b1 * w1 - k12 * q2
        a2 = tc[1] - 0.7 * b2 * w2 - k12 * q1
        det = fl * fl * (J1 * J2 - J12 * J12)
        dx[0] = w1
        dx[2] = w2
        dx[1] = fl * (J2 * a1 - J12 * a2) / det
        dx[3] = fl * (J1 * a2 - J12 * a1) / det
        return dx
    if code == 4:
        tau, R = p[0], p[1]
        for j in range(4):
            v = (u[j] - x[10 + j]) / tau
            dx[10 + j] = min(max(v, -R), R)
    # M [w1', w2'] = [tau1 - f1, tau2 - f2]
    a1 = tau1 - f1
    a2 = tau2 - f2
    det = J1 * J2 - J12 * J12
    dx[0] = w1
    dx[2] = w2
    dx[1] = (J2 * a1 - J12 * a2) / det
    dx[3] = (J1 * a2 - J12 * a1) / det
    return dx


@njit(cache=False)
def _simulate(U, code, p, nm, sub, dt, x0):
    n = U.shape[0]
    x = x0.copy()
    Y = np.empty((n, 2))
    h = dt / sub
    for k in range(n):
        Y[k, 0] = x[0]
        Y[k, 1] = x[2]
        u = U[k]
        for _ in range(sub):
            k1_ = _rhs(x, u, code, p, nm)
            k2_ = _rhs(x + 0.5 * h * k1_, u, code, p, nm)
            k3_ = _rhs(x + 0.5 * h * k2_, u, code, p, nm)
            k4_ = _rhs(x + h * k3_, u, code, p, nm)
            x = x + (h / 6.0) * (k1_ + 2 * k2_ + 2 * k3_ + k4_)
    return Y


def simulate(effect, ep, nom, Ucmd):
    """Noise-free joint angles for the commanded tensions Ucmd (incl. run-in)."""
    code = CODE[effect]
    U = Ucmd.copy()
    p = np.zeros(6)
    if effect == "input_delay":
        D = ep["delay_samples"]
        U = np.vstack([np.repeat(Ucmd[:1], D, axis=0), Ucmd[:-D]])
        code = 0
    elif effect == "coulomb_friction":
        p[:2] = ep["Fc"], ep["eps"]
    elif effect == "backlash":
        p[:4] = 0.5 * ep["play_total_rad"], ep["link_fraction"], ep["kg"], ep["cg"]
    elif effect == "actuator_lag":
        p[:2] = ep["tau"], ep["rate"]
    elif effect == "saturation":
        p[0] = ep["Tmax"]
    elif effect == "dead_zone":
        p[0] = ep["Ts"]
    elif effect == "hysteresis":
        p[:2] = ep["alpha"], ep["z0"]
    elif effect == "nonlinear_stiffness":
        p[0] = ep["k3_over_k"]
    elif effect == "gravity":
        p[:2] = ep["mgl"], ep["phi0"]
    nm = np.array([nom[k] for k in ("J1", "J2", "J12", "k1", "k2", "k12", "b1", "b2", "r1", "r2")])
    x0 = np.zeros(14)
    x0[10:14] = Ucmd[0]
    return _simulate(np.ascontiguousarray(U), code, p, nm, SUB, DT, x0)


def records(
    effect: str, seed: int, train_s: float = 240.0, valid_s: float = 150.0
) -> tuple[dict[str, Any], Dataset, Dataset]:
    """The case's effect parameters, training and validation data (the probe's make_case;
    ``train_s``, ``valid_s``: the records' durations in seconds)."""
    idx = EFFECTS.index(effect)
    nom = nominal_params(np.random.default_rng([seed, 0]))
    ep = effect_params(effect, np.random.default_rng([seed, 1, idx]), nom)
    rng_n = np.random.default_rng([seed, 2, idx])
    nrun = round(RUNIN / DT)
    out = []
    for name, dur, exseed in (("train", train_s, seed * 10 + 1), ("valid", valid_s, seed * 10 + 2)):
        t, U = excitation(exseed, dur)
        Y = simulate(effect, ep, nom, U)
        U, Y = U[nrun:], Y[nrun:]
        t = np.round(t[nrun:] - t[nrun], 2)
        Ym = Y + 0.02 * Y.std(axis=0) * rng_n.standard_normal(Y.shape)
        e = Experiment(t=t, u=np.round(U, 4), y=np.round(Ym, 6), name=name)
        out.append(Dataset(inputs=("T1", "T2", "T3", "T4"), outputs=("q1", "q2"),
                           experiments=(e,), dt=DT))  # fmt: skip
    return ep, out[0], out[1]


def case(shared: Any, job: tuple[str, int]) -> dict[str, Any]:
    """One diagnosis at default options."""
    from tendonkit.diagnose import diagnose

    effect, seed = job
    params, train, valid = records(effect, seed)
    t0 = time.perf_counter()
    d = diagnose(train, valid)
    return result_row(effect, seed, params, d, time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", default="4101,4102", help="comma-separated seeds")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--out", default=None, help="JSON file for the results")
    args = parser.parse_args()
    jobs = [(e, int(s)) for e in EFFECTS for s in args.seeds.split(",")]
    run_cases(case, jobs, args.jobs, None, args.out)


if __name__ == "__main__":
    main()
