"""Diagnose benchmark: time and outcome of ``diagnose`` on 20 000 samples, 4 inputs, 2 outputs.

The data come from the simulated tendon robot (``tendonkit.fmu.plant.Plant``, plant spec §12
protocols, sensor noise on), with one hidden effect switched on (default: effect A, capstan
friction, at its default magnitude).  Training: one lap of circles at 1–12 cm plus pseudo-random
motion, 12 000 samples in all; validation: pseudo-random motion with a new seed plus clockwise
circles at 1.5, 6.5 and 11.5 cm, 8 000 samples — 20 000 samples together.  Inputs are the four
measured tensions, outputs the joint angles q1 and q2.  Every built-in effect is tried with the
given baseline (default ARX(3, 3, 1), the plant suite's baseline, and tendonkit's default ARX).

Times are wall-clock seconds of the ``diagnose`` call alone (data generation excluded), median
of ``--repeat`` runs.  The target is 60 s on a 2-core machine.

Usage::

    python benchmarks/bench_diagnose.py --out diagnose.json

No peer package is needed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from typing import Any

import numpy as np

TARGET_S = 60.0


def plant_data(effect: dict[str, Any], seed: int = 1) -> tuple[Any, Any]:
    """Training (12k) and validation (8k) data from the plant with ``effect`` on."""
    from tendonkit.dataset import Dataset, Experiment
    from tendonkit.fmu._config import PlantConfig
    from tendonkit.fmu.plant import Plant
    from tendonkit.robot.protocol import circles, pseudo_random

    cfg = PlantConfig(noise_on=True, seed=seed, **effect)

    def dataset(parts: list[tuple[str, Any]], n: int) -> Dataset:
        exps = []
        for i, (name, proto) in enumerate(parts):
            plant = Plant(cfg.replace(seed=seed + i))
            plant.reset()
            log = plant.record(proto.u)
            exps.append(Experiment(t=log["t"], u=log["T_meas"], y=log["q"][:, :2], name=name))
        ds = Dataset(
            inputs=("T1", "T2", "T3", "T4"), outputs=("q1", "q2"), experiments=tuple(exps), dt=0.03
        )
        total = sum(e.n_samples for e in ds.experiments)
        assert total >= n, (total, n)
        return ds

    train_circles = circles(laps=1, radii=[0.01 * r for r in range(1, 13)])
    n_circ = train_circles.u.shape[0]
    train_random = pseudo_random(duration=(12_000 - n_circ) * 0.03, seed=seed)
    valid_circles = circles(radii=[0.015, 0.065, 0.115], laps=1, clockwise=True)
    valid_random = pseudo_random(
        duration=(8_000 - valid_circles.u.shape[0]) * 0.03, seed=seed + 1000
    )
    train = dataset([("circles", train_circles), ("random", train_random)], 11_900)
    valid = dataset([("random", valid_random), ("circles", valid_circles)], 7_900)
    return train, valid


def run(method: str, options: dict[str, Any], effect: dict[str, Any], repeat: int) -> dict:
    """Time ``diagnose`` and report its outcome."""
    from tendonkit.diagnose import diagnose

    train, valid = plant_data(effect)
    times, d = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        d = diagnose(train, valid, method=method, options=options)
        times.append(time.perf_counter() - t0)
    assert d is not None
    best = d.best
    return {
        "method": method,
        "options": options,
        "effect": effect,
        "samples": {"train": train.n_samples, "valid": valid.n_samples},
        "effects_tried": d.settings["effects"],
        "time_s": statistics.median(times),
        "times_s": times,
        "cause": d.cause,
        "gain": best.gain if best else 0.0,
        "p_adjusted": best.p_adjusted if best else None,
        "baseline_fit": float(np.mean(list(d.baseline_fit.values()))),
        "within_target": statistics.median(times) <= TARGET_S,
    }


def main() -> None:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--out", default=None, help="write the results as JSON here")
    args = parser.parse_args()
    effect = {"friction_on": True}
    rows = [
        run("arx", {"na": 3, "nb": 3, "nk": 1, "bilinear": True}, effect, args.repeat),
        run("arx", {"na": 3, "nb": 3, "nk": 1}, effect, args.repeat),
        run("arx", {}, effect, args.repeat),
    ]
    info = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "load_average": os.getloadavg(),
        },
        "results": rows,
    }
    print("| baseline | samples (train + valid) | time [s] | cause | gain [points] | within 60 s |")
    print("|---|---|---:|---|---:|---|")
    for r in rows:
        opts = ", ".join(f"{k}={v}" for k, v in r["options"].items()) or "defaults"
        n = r["samples"]
        print(
            f"| {r['method']} ({opts}) | {n['train']} + {n['valid']} | {r['time_s']:.1f} | "
            f"{r['cause']} | {r['gain']:+.2f} | {'yes' if r['within_target'] else 'no'} |"
        )
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            json.dump(info, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
