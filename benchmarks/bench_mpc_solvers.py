"""Solve times of the MPC controllers: cvxpy design path vs direct fast path, Clarabel vs OSQP.

Representative problem (issue 5): a random stable 8-state system with 4 tendon-force inputs
(20..190 N) and 2 joint-angle outputs (±1 rad soft bounds), horizon N = 20, dt = 30 ms, run in
closed loop for a few hundred samples on steps and sines with a 20 % gain mismatch and an
output bias (so the disturbance estimate and the soft constraints are exercised).  For each
solver and path it prints the median, 99th percentile and maximum of ``StepResult.solve_time_s``
(setting the parameters and solving; the first 5 samples are dropped as warm-up), the
thread CPU time of the whole step (insensitive to other processes on a loaded machine) and
the largest difference of the applied inputs from the design path's.

Further tables: the nonlinear MPC on a two-state sparse map (whole-step time: linearisation
plus QP), and an identified ARX(8, 8) model whose 48-state realisation is reduced to its
minimal order.

Targets (issue 5, not asserted): linear MPC median <= 2 ms and p99 <= 5 ms; nonlinear MPC
p99 <= 15 ms per step.

Usage::

    python benchmarks/bench_mpc_solvers.py [--steps 600] [--quick]
"""

from __future__ import annotations

import argparse
import gc
import os
import time

import numpy as np

from tendonkit.mpc import LinearMPC, NonlinearMPC, Solver, Weights
from tendonkit.mpc.examples import random_tendon_model, tendon_sparse_map
from tendonkit.mpc.nonlinear import SparseMapDynamics
from tendonkit.realize import to_state_space
from tendonkit.schema import Model

U0 = np.full(4, 105.0)


def reference(n: int) -> np.ndarray:
    """Steps, then two sines (rad)."""
    t = np.arange(n) * 0.03
    ref = np.c_[0.45 * np.sin(2 * np.pi * 0.4 * t), 0.35 * np.cos(2 * np.pi * 0.25 * t)]
    q = n // 4
    ref[:q] = 0.0
    ref[q // 4 : q] = [0.4, -0.3]
    ref[q : 2 * q] = [-0.3, 0.45]
    return ref


def run_linear(
    ctrl: LinearMPC, plant: Model, ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed loop with a plant 20 % stronger than the model and a 0.03 rad bias."""
    ss = to_state_space(plant)
    x = np.linalg.solve(np.eye(ss.A.shape[0]) - ss.A, ss.B @ U0)
    ctrl.reset(U0, ss.C @ x)
    times, cpu, inputs = [], [], []
    gc.collect()
    for k in range(len(ref)):
        c0 = time.thread_time()
        res = ctrl.step(
            ss.C @ x + 0.03, ref[k + 1 : k + 1 + ctrl.horizon] if k + 1 < len(ref) else ref[-1:]
        )
        cpu.append(time.thread_time() - c0)
        x = ss.A @ x + ss.B @ (U0 + 1.2 * (res.u - U0))
        times.append(res.solve_time_s)
        inputs.append(res.u)
    return np.array(times[5:]), np.array(cpu[5:]), np.array(inputs)


def run_nonlinear(
    ctrl: NonlinearMPC, plant: Model, ref: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    dyn = SparseMapDynamics(plant)
    x = np.zeros(dyn.nz)
    ctrl.reset(U0, dyn.C @ x)
    solve, step, cpu, inputs = [], [], [], []
    gc.collect()
    for k in range(len(ref)):
        c0 = time.thread_time()
        res = ctrl.step(
            dyn.C @ x + 0.02, ref[k + 1 : k + 1 + ctrl.horizon] if k + 1 < len(ref) else ref[-1:]
        )
        cpu.append(time.thread_time() - c0)
        x = dyn.step(x, res.u)
        solve.append(res.solve_time_s)
        step.append(res.step_time_s)
        inputs.append(res.u)
    return np.array(solve[5:]), np.array(step[5:]), np.array(cpu[5:]), np.array(inputs)


def row(label: str, t: np.ndarray, cpu: np.ndarray | None = None, extra: str = "") -> str:
    """Wall-clock median/p99/max, then the median/p99 CPU time of the whole step (ms)."""
    ms = 1e3 * t
    cols = f"{np.median(ms):7.2f} {np.percentile(ms, 99):7.2f} {ms.max():7.2f}"
    if cpu is not None:
        c = 1e3 * cpu
        cols += f"   {np.median(c):7.2f} {np.percentile(c, 99):7.2f}"
    else:
        cols += " " * 18
    return f"  {label:<40} {cols}   {extra}"


def header(title: str) -> None:
    print(f"\n{title}")
    print(f"  {'':<40} {'median':>7} {'p99':>7} {'max':>7}   {'cpu med':>7} {'cpu p99':>7}   (ms)")


def bench_linear(steps: int) -> None:
    plant = random_tendon_model(8, seed=0)
    ref = reference(steps)
    header(f"Linear MPC: n=8, nu=4, ny=2, N=20, {steps} closed-loop samples (solve time)")
    for solver in ("clarabel", "osqp"):
        base = None
        for fast in (False, True):
            t0 = time.perf_counter()
            ctrl = LinearMPC(plant, weights=Weights(R=1e-3), solver=Solver(name=solver, fast=fast))
            build = time.perf_counter() - t0
            t, cpu, u = run_linear(ctrl, plant, ref)
            if base is None:
                base = u
            diff = np.max(np.abs(u - base))
            path = "fast  " if fast else "design"
            form = ctrl._qp.formulation
            print(
                row(
                    f"{solver:<8} {path} [{form}]",
                    t,
                    cpu,
                    f"build {build:4.2f} s, fallbacks {ctrl.n_fallbacks}, "
                    f"max|Δu| vs design {diff:.0e} N",
                )
            )
    print("  variants (fast path):")
    for solver, form, opts in (
        ("clarabel", "condensed", {}),
        ("osqp", "sparse", {}),
        ("clarabel", "sparse", {"iterative_refinement_enable": True}),
    ):
        ctrl = LinearMPC(
            plant,
            weights=Weights(R=1e-3),
            solver=Solver(name=solver, formulation=form, options=opts),
        )
        t, cpu, _ = run_linear(ctrl, plant, ref)
        label = f"{solver:<8} fast   [{form}]{' refinement on' if opts else ''}"
        print(row(label, t, cpu, f"fallbacks {ctrl.n_fallbacks}"))


def bench_nonlinear(steps: int) -> None:
    model = tendon_sparse_map(bend=1.5)
    plant = tendon_sparse_map(bend=1.5, arm=0.0017)
    ref = reference(steps) * 1.2
    header(f"Nonlinear MPC: sparse map, nz=2, nu=4, ny=2, N=20, {steps} samples")
    for solver in ("clarabel", "osqp"):
        base = None
        for fast in (False, True):
            t0 = time.perf_counter()
            ctrl = NonlinearMPC(
                model, weights=Weights(R=1e-3), solver=Solver(name=solver, fast=fast)
            )
            build = time.perf_counter() - t0
            solve, step, cpu, u = run_nonlinear(ctrl, plant, ref)
            if base is None:
                base = u
            path = "fast  " if fast else "design"
            diff = np.max(np.abs(u - base))
            print(row(f"{solver:<8} {path} QP solve", solve, None, f"build {build:4.2f} s"))
            print(
                row(
                    f"{solver:<8} {path} whole step",
                    step,
                    cpu,
                    f"fallbacks {ctrl.n_fallbacks}, max|Δu| vs design {diff:.0e} N",
                )
            )


def bench_arx(steps: int) -> None:
    import tendonkit as tk
    from tendonkit.testsystems import simulate_truth

    truth = random_tendon_model(8, seed=0)
    data, _ = simulate_truth(truth, 3000, noise=0.01, seed=3)
    arx = tk.identify(data, "arx", na=8, nb=8)
    ref = reference(steps)
    header(f"ARX(8, 8) identified from data (fast path, {steps} samples)")
    for solver in ("clarabel", "osqp"):
        for reduce in ("none", "minreal"):
            t0 = time.perf_counter()
            ctrl = LinearMPC(
                arx, weights=Weights(R=1e-3), solver=Solver(name=solver), reduce=reduce
            )
            build = time.perf_counter() - t0
            t, cpu, _ = run_linear(ctrl, truth, ref)
            n0 = ctrl.prediction.n_realized
            print(
                row(
                    f"{solver:<8} reduce={reduce:<8} n={ctrl.n_states}/{n0}",
                    t,
                    cpu,
                    f"build {build:4.2f} s, fallbacks {ctrl.n_fallbacks}",
                )
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=600, help="closed-loop samples per case")
    parser.add_argument("--quick", action="store_true", help="linear MPC table only")
    args = parser.parse_args()
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"{os.cpu_count()} CPUs, load average {load} (wall-clock p99 suffers from other load;")
    print("the CPU columns are the thread's own time for the whole step)")
    bench_linear(args.steps)
    if not args.quick:
        bench_nonlinear(args.steps)
        bench_arx(args.steps)


if __name__ == "__main__":
    main()
