"""diagnose at default options on a plant it was not designed on: a chain of three masses.

Run from the repository root, one BLAS thread (benchmarks/README.md gives the results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_diagnose_chain.py --jobs 2

Three unit masses in a line, the first tied to the ground by a spring of 200 N/m, neighbours
coupled by springs of 400 N/m, every spring and the ground with dampers of 1.5 N·s/m
(lightly damped); a band-limited random force (4 Hz, rms 20 N) on the first mass; the three
positions measured at 5 ms with 1 % white noise.  One hidden effect per case, its magnitude
drawn from the case's seed:

- ``coulomb_friction``: a dry friction of 1–3 N on the middle mass;
- ``backlash``: play of half-width 4–10 mm in the coupling of the first two masses
  (*between two bodies*);
- ``nonlinear_stiffness``: a hardening coupling of the last two masses,
  ``k (d + α d³)``, α 500–2000 (*between two bodies*);
- ``input_delay``: a dead time of 10–20 samples;
- ``saturation``: the force clipped at 15–25 N;
- ``dead_zone``: a force dead band of 4–8 N;
- ``actuator_lag``: a force slew limit of 300–800 N/s.

Training and validation are two records of 4,000 samples with different input seeds; the
diagnosis is ``diagnose(train, valid)``, nothing set.  A case is named right when the first
cause is the hidden effect (``none``: no cause).

``--plant tanks`` runs a second plant instead: two tanks in cascade at 1 s, the lower level
measured (1 % noise), outflows ``0.5·sqrt(h)``, a pump of gain 0.25 driven around 5 V (a
0.02 Hz band-limited input of std 1 V), tank areas ``--areas`` (default 2 and 3: time
constants of 20 and 30 s).  Its effects: a dead time of 15–40 s, a pump that starts at
4–4.6 V (``dead_zone``), a pump limited at 5.6–6.2 V (``saturation``), a slew limit of
0.02–0.05 V/s (``actuator_lag``) and a pump curve ``u + c (u - 5)²`` (``static_nonlinearity``).
The square root of the outflows is the plant's own nonlinear dynamics (a time constant that
moves with the level; a `none` case that names a cause is wrong here).

``--plant sea`` runs a third: a series-elastic actuator at 5 ms (written on 2026-11-27, after
the loop of ``actuator_lag`` was built on the robot, and tuned on nothing).  A proportional
force loop drives a motor, ``dθ/dt = kp (u - F)``, whose spring pushes a load,
``F = k (θ - x)``, ``m ẍ = F - c ẋ - k_l x``; the force command ``u`` (random steps held
50 ms, rms 20 N) is the input, the load position ``x`` (1 % noise) the output.  The plant's
own parameters are drawn from the seed too (``k`` 2,000–5,000 N/m, ``m`` 0.5–2 kg, ``c``
2–8 N·s/m, ``k_l`` 200–800 N/m, ``kp`` 0.01–0.03 m/s per N).  Its effects: the motor's speed
limited at 30–60 % of the 95 % quantile of the speed the free loop asks for
(``actuator_lag``: a rate limit *inside* the force loop), a dry friction of 1–3 N on the
load (``coulomb_friction``), the command clipped at 15–25 N (``saturation``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import butter, lfilter

from tendonkit.dataset import Dataset, Experiment
from tendonkit.parallel import run_tasks

DT = 0.005
EFFECTS = (
    "none",
    "coulomb_friction",
    "backlash",
    "nonlinear_stiffness",
    "input_delay",
    "saturation",
    "dead_zone",
    "actuator_lag",
)
RANGES = {
    "coulomb_friction": ("fc", 1.0, 3.0),
    "backlash": ("b", 0.004, 0.01),
    "nonlinear_stiffness": ("alpha", 500.0, 2000.0),
    "input_delay": ("samples", 10, 20),
    "saturation": ("limit", 15.0, 25.0),
    "dead_zone": ("th", 4.0, 8.0),
    "actuator_lag": ("rate", 300.0, 800.0),
}


def draw(
    effect: str, seed: int, ranges: dict[str, tuple[str, float, float]] = RANGES
) -> dict[str, float]:
    """The effect's magnitude, drawn in its range (``RANGES``, ``TANK_RANGES``) from the seed."""
    if effect == "none":
        return {}
    key, lo, hi = ranges[effect]
    value = float(np.random.default_rng(seed).uniform(lo, hi))
    return {key: round(value) if key == "samples" else value}


def chain(effect: str, p: dict[str, float], seed: int, n: int = 4000) -> Dataset:
    """One record of the chain with ``effect`` hidden (parameters ``p``)."""
    rng = np.random.default_rng(seed)
    u = lfilter(*butter(2, 4.0, fs=1 / DT), rng.standard_normal(n))
    u = 20.0 * u / u.std()
    v = u.copy()
    if effect == "input_delay":
        d = int(p["samples"])
        v = np.concatenate([np.zeros(d), u[:-d]])
    elif effect == "dead_zone":
        v = np.sign(u) * np.maximum(np.abs(u) - p["th"], 0.0)
    elif effect == "saturation":
        v = np.clip(u, -p["limit"], p["limit"])
    elif effect == "actuator_lag":
        step = p["rate"] * DT
        for k in range(1, n):
            v[k] = v[k - 1] + np.clip(u[k] - v[k - 1], -step, step)
    k0, k12, k23, c = 200.0, 400.0, 400.0, 1.5
    x, w = np.zeros(3), np.zeros(3)
    y = np.empty((n, 3))
    sub = 20
    h = DT / sub
    for i in range(n):
        y[i] = x
        for _ in range(sub):
            d12, d23 = x[0] - x[1], x[1] - x[2]
            if effect == "backlash":
                d12 = np.sign(d12) * max(abs(d12) - p["b"], 0.0)
            f12 = k12 * d12 + c * (w[0] - w[1])
            f23 = k23 * d23 + c * (w[1] - w[2])
            if effect == "nonlinear_stiffness":
                f23 += k23 * p["alpha"] * d23**3
            fr = p["fc"] * np.tanh(w[1] / 1e-3) if effect == "coulomb_friction" else 0.0
            a = np.array([v[i] - k0 * x[0] - c * w[0] - f12, f12 - f23 - fr, f23])
            w = w + h * a
            x = x + h * w
    y = y + 0.01 * y.std(axis=0) * np.random.default_rng(seed + 1).standard_normal(y.shape)
    e = Experiment(t=DT * np.arange(n), u=u[:, None], y=y, name=f"chain{seed}")
    return Dataset(inputs=("F",), outputs=("x1", "x2", "x3"), experiments=(e,), dt=DT)


TANK_EFFECTS = ("none", "input_delay", "dead_zone", "saturation", "actuator_lag")
TANK_EFFECTS += ("static_nonlinearity",)
TANK_RANGES = {
    "input_delay": ("samples", 15, 40),
    "dead_zone": ("th", 4.0, 4.6),
    "saturation": ("limit", 5.6, 6.2),
    "actuator_lag": ("rate", 0.02, 0.05),
    "static_nonlinearity": ("c", 0.15, 0.3),
}


def tanks(
    effect: str, p: dict[str, float], seed: int, areas: tuple[float, float], n: int = 3000
) -> Dataset:
    """One record of the two tanks with ``effect`` hidden (parameters ``p``)."""
    rng = np.random.default_rng(seed)
    u = lfilter(*butter(2, 0.02, fs=1.0), rng.standard_normal(n))
    u = 5.0 + u / u.std()
    v = u.copy()
    if effect == "input_delay":
        d = int(p["samples"])
        v = np.concatenate([np.full(d, u[0]), u[:-d]])
    elif effect == "dead_zone":
        v = np.where(u > p["th"], u, 0.0)
    elif effect == "saturation":
        v = np.minimum(u, p["limit"])
    elif effect == "actuator_lag":
        for k in range(1, n):
            v[k] = v[k - 1] + np.clip(u[k] - v[k - 1], -p["rate"], p["rate"])
    elif effect == "static_nonlinearity":
        v = u + p["c"] * (u - 5.0) ** 2
    h1 = h2 = (0.25 * 5.0 / 0.5) ** 2
    y = np.empty(n)
    h = 0.1
    for i in range(n):
        y[i] = h2
        for _ in range(10):
            q1, q2 = 0.5 * np.sqrt(max(h1, 0.0)), 0.5 * np.sqrt(max(h2, 0.0))
            h1 += h / areas[0] * (0.25 * v[i] - q1)
            h2 += h / areas[1] * (q1 - q2)
    y = y + 0.01 * y.std() * np.random.default_rng(seed + 1).standard_normal(n)
    e = Experiment(t=np.arange(n, dtype=float), u=u[:, None], y=y[:, None], name=f"tanks{seed}")
    return Dataset(inputs=("pump",), outputs=("level",), experiments=(e,), dt=1.0)


SEA_EFFECTS = ("none", "actuator_lag", "coulomb_friction", "saturation")
SEA_RANGES = {
    "actuator_lag": ("speed_share", 0.3, 0.6),
    "coulomb_friction": ("fc", 1.0, 3.0),
    "saturation": ("limit", 15.0, 25.0),
}


def sea_plant(seed: int) -> dict[str, float]:
    """The series-elastic actuator's own parameters, drawn from the case's seed."""
    g = np.random.default_rng(seed + 7000)
    return {
        "k": g.uniform(2000.0, 5000.0),
        "m": g.uniform(0.5, 2.0),
        "c": g.uniform(2.0, 8.0),
        "kl": g.uniform(200.0, 800.0),
        "kp": g.uniform(0.01, 0.03),
    }


def sea(
    effect: str, p: dict[str, float], seed: int, plant: dict[str, float], n: int = 6000
) -> tuple[Dataset, np.ndarray]:
    """One record of the series-elastic actuator with ``effect`` hidden, and the motor speed
    its force loop asked for (``p["vmax"]``: the motor's speed limit, for ``actuator_lag``)."""
    u = np.repeat(np.random.default_rng(seed).normal(0.0, 20.0, n // 10 + 1), 10)[:n]
    if effect == "saturation":
        u_in = np.clip(u, -p["limit"], p["limit"])
    else:
        u_in = u
    vmax = p["vmax"] if effect == "actuator_lag" else np.inf
    k, m, c, kl, kp = (plant[key] for key in ("k", "m", "c", "kl", "kp"))
    th = x = w = 0.0
    y, speed = np.empty(n), np.empty(n)
    sub = 20  # substeps: the friction's tanh(w/1e-3) is stiff (explicit Euler, as the chain)
    h = DT / sub
    for i in range(n):
        y[i] = x
        speed[i] = kp * (u_in[i] - k * (th - x))
        for _ in range(sub):
            f = k * (th - x)
            th += h * min(max(kp * (u_in[i] - f), -vmax), vmax)
            fr = p["fc"] * np.tanh(w / 1e-3) if effect == "coulomb_friction" else 0.0
            w += h * (f - c * w - kl * x - fr) / m
            x += h * w
    y = y + 0.01 * y.std() * np.random.default_rng(seed + 1).standard_normal(n)
    e = Experiment(t=DT * np.arange(n), u=u[:, None], y=y[:, None], name=f"sea{seed}")
    return Dataset(inputs=("F_cmd",), outputs=("x",), experiments=(e,), dt=DT), speed


def sea_case(effect: str, seed: int) -> tuple[dict[str, float], Dataset, Dataset]:
    """The series-elastic actuator's case: its effect's parameters, training record (``seed``)
    and validation record (``seed + 500``); the speed limit is a share of the speed the free
    loop asks for."""
    p, sp = draw(effect, seed, SEA_RANGES), sea_plant(seed)
    if effect == "actuator_lag":
        asked = np.abs(sea("none", {}, seed, sp)[1])
        p["vmax"] = p["speed_share"] * float(np.quantile(asked, 0.95))
    return p, sea(effect, p, seed, sp)[0], sea(effect, p, seed + 500, sp)[0]


def case(shared: Any, job: tuple[str, int]) -> dict[str, Any]:
    """One diagnosis at default options."""
    from tendonkit.diagnose import diagnose

    effect, seed = job
    plant, areas = shared
    if plant == "tanks":
        p = draw(effect, seed, TANK_RANGES)
        train, valid = tanks(effect, p, seed, areas), tanks(effect, p, seed + 500, areas)
    elif plant == "sea":
        p, train, valid = sea_case(effect, seed)
    else:
        p = draw(effect, seed)
        train, valid = chain(effect, p, seed), chain(effect, p, seed + 500)
    t0 = time.perf_counter()
    d = diagnose(train, valid)
    return result_row(effect, seed, p, d, time.perf_counter() - t0)


def result_row(effect: str, seed: int, params: Any, d: Any, seconds: float) -> dict[str, Any]:
    """One case's row of the results (also bench_diagnose_pantilt.py's)."""
    return {
        "effect": effect,
        "seed": seed,
        "params": params,
        "causes": list(d.causes),
        "right": d.cause == effect,
        "baseline": d.baseline_method,
        "unfit": d.unfit is not None,
        "explains": d.best.test.get("explains") if d.best is not None else None,
        "findings": [
            {"effect": f.effect, "gain": f.gain, "p_adjusted": f.p_adjusted} for f in d.findings[:3]
        ],
        "seconds": seconds,
    }


def run_cases(
    case_fn: Any, jobs: list[tuple[str, int]], n_jobs: int, shared: Any, out: Any
) -> None:
    """Run every case on ``n_jobs`` workers, print a line per case and the score, and write the
    rows to ``out`` (a JSON file) when given (also bench_diagnose_pantilt.py's)."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = [{} for _ in jobs]
    for o in run_tasks(case_fn, jobs, jobs=n_jobs, shared=shared):
        if o.error is not None:
            raise SystemExit(f"{jobs[o.index]} failed: {o.error}")
        r = rows[o.index] = o.value
        top = ", ".join(
            f"{f['effect']} {f['gain']:+.2f} ({f['p_adjusted']:.0e})" for f in r["findings"]
        )
        mark = "right" if r["right"] else "MISS"
        print(
            f"{r['effect']:20s} {r['seed']}  {mark:5s} causes {', '.join(r['causes'])} "
            f"(via {r['baseline']}; {top}) {r['seconds']:.0f} s",
            flush=True,
        )
    print(f"named right: {sum(r['right'] for r in rows)} of {len(rows)}")
    if out:
        machine = {"load_before": load, "load_after": os.getloadavg()[0]}
        machine["wall_s"] = time.perf_counter() - t0
        Path(out).write_text(json.dumps({"rows": rows, "machine": machine}, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", default="801,802", help="comma-separated seeds")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    parser.add_argument("--out", default=None, help="JSON file for the results")
    parser.add_argument("--plant", choices=("chain", "tanks", "sea"), default="chain")
    parser.add_argument("--areas", default="2,3", help="the tanks' areas (time constants /10)")
    args = parser.parse_args()
    effects = {"tanks": TANK_EFFECTS, "sea": SEA_EFFECTS}.get(args.plant, EFFECTS)
    jobs = [(e, int(s)) for e in effects for s in args.seeds.split(",")]
    areas = tuple(float(a) for a in args.areas.split(","))
    run_cases(case, jobs, args.jobs, (args.plant, areas), args.out)


if __name__ == "__main__":
    main()
