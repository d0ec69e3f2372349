"""Identification benchmark: tendonkit's N4SID and ARX side by side with SIPPY and nfoursid.

The 4-input, 2-output, order-8 test system (``random_state_space(8, 4, 2, seed=0)``) is
excited with white Gaussian inputs, its outputs get 1 % noise, and every method identifies a
model from ``N`` training samples.  Each model is scored by its free-run fit (initial state
estimated, the same policy for every method) on a fresh 20 000-sample validation record
(another seed); the true system's own fit on that record is the noise ceiling.

Every (method, N) runs in its own subprocess with a time limit and a memory limit, so a peer
that hangs or runs out of memory is recorded as ``timeout`` or ``error`` with the reason.
Fast runs are repeated and the median time is reported.  Times are wall-clock seconds of the
identification call alone (data generation and scoring excluded); tendonkit's time includes
the training-fit simulation that every tendonkit model carries in its provenance.

Usage::

    python benchmarks/bench_identify.py --sizes 2000,20000,200000 --out results.json

This is not a test; it needs the peers in ``benchmarks/requirements.txt``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

#: Methods in table order: key -> label.
METHODS: dict[str, str] = {
    "tendonkit-n4sid": "tendonkit n4sid (order 8)",
    "tendonkit-arx": "tendonkit arx (defaults: na=nb=8, nk=1)",
    "sippy-n4sid": "SIPPY N4SID (order 8, f=10)",
    "sippy-arx": "SIPPY ARX (MISO, na=nb=8, delay 1)",
    "nfoursid": "nfoursid (order 8, 10 block rows)",
}
N_VALID = 20_000
NOISE = 0.01
HORIZON = 10  # block rows for every subspace method (tendonkit's default at order 8)
MEMORY_LIMIT = 8 * 1024**3  # bytes of address space per worker
REPEAT_BELOW = 10.0  # seconds: runs faster than this are repeated


def _data(n: int, seed: int) -> Any:
    from tendonkit.testsystems import random_state_space, simulate_truth

    truth = random_state_space(8, 4, 2, seed=0)
    data, _ = simulate_truth(truth, n, noise=NOISE, seed=seed)
    return truth, data


def _score(model: Any, valid: Any) -> list[float]:
    """Free-run fit per output on the validation record (initial state estimated)."""
    import tendonkit as tk

    e = valid.experiments[0]
    return [float(v) for v in tk.fit(e.y, tk.simulate(model, e.u, y=e.y))]


def _as_state_space(truth: Any, A: Any, B: Any, C: Any, D: Any) -> Any:
    import numpy as np

    from tendonkit.schema import StateSpace

    rep = StateSpace(
        A=np.asarray(A, float),
        B=np.asarray(B, float),
        C=np.asarray(C, float),
        D=np.asarray(D, float),
    )
    return truth.replace(representation=rep, name="peer model")


def _sippy_arx_model(truth: Any, m: Any, na: int, nb: int) -> Any:
    """SIPPY's MISO ARX polynomials as a tendonkit ARX model (diagonal A matrices, nk = 1).

    SIPPY regresses output ``i`` on its own past only: ``y_i[k] + Σ_l a_il y_i[k-l] =
    Σ_j Σ_l b_ijl u_j[k-1-l]`` with ``DENOMINATOR[i][j] = [1, a_i1, ...]`` (the same for every
    ``j``) and ``NUMERATOR[i][j][l] = b_ijl``.
    """
    import numpy as np

    from tendonkit.schema import ARX

    ny, nu = len(m.NUMERATOR), len(m.NUMERATOR[0])
    A = [np.zeros((ny, ny)) for _ in range(na)]
    B = [np.zeros((ny, nu)) for _ in range(nb)]
    for i in range(ny):
        den = np.asarray(m.DENOMINATOR[i][0], float)
        for lag in range(na):
            A[lag][i, i] = den[lag + 1]
        for j in range(nu):
            num = np.asarray(m.NUMERATOR[i][j], float)
            for lag in range(nb):
                B[lag][i, j] = num[lag]
    rep = ARX(A=tuple(A), B=tuple(B), nk=(1,) * nu)
    return truth.replace(representation=rep, name="SIPPY ARX")


def _identify(method: str, truth: Any, data: Any) -> Any:
    """Run one method on ``data`` and return a tendonkit model (the timed call)."""
    e = data.experiments[0]
    if method == "tendonkit-n4sid":
        from tendonkit.plugins.n4sid import N4SID

        return N4SID(order=8).identify(data)
    if method == "tendonkit-arx":
        import tendonkit as tk
        from tendonkit.errors import PluginError

        try:
            return tk.identify(data, "arx")
        except PluginError:  # another plugin is broken: use the ARX plugin directly
            from tendonkit.plugins.arx import ARX

            return ARX().identify(data)
    if method == "sippy-n4sid":
        from sippy_unipi import system_identification

        with contextlib.redirect_stdout(io.StringIO()):
            m = system_identification(e.y, e.u, "N4SID", SS_fixed_order=8, SS_f=HORIZON)
        return _as_state_space(truth, m.A, m.B, m.C, m.D)
    if method == "sippy-arx":
        from sippy_unipi import system_identification

        with contextlib.redirect_stdout(io.StringIO()):
            m = system_identification(e.y, e.u, "ARX", ARX_orders=[8, 8, 0])
        return _sippy_arx_model(truth, m, 8, 8)
    if method == "nfoursid":
        import pandas as pd
        from nfoursid.nfoursid import NFourSID

        cols_u = [f"u{j}" for j in range(e.u.shape[1])]
        cols_y = [f"y{j}" for j in range(e.y.shape[1])]
        frame = pd.DataFrame(dict(zip(cols_u + cols_y, [*e.u.T, *e.y.T])))
        n4 = NFourSID(frame, output_columns=cols_y, input_columns=cols_u, num_block_rows=HORIZON)
        n4.subspace_identification()
        ss, _ = n4.system_identification(rank=8)
        return _as_state_space(truth, ss.a, ss.b, ss.c, ss.d)
    raise ValueError(f"unknown method {method!r}")


def _warm_up(method: str) -> None:
    """Import what ``method`` needs, so that import time is not counted as identification."""
    import importlib

    modules = {
        "tendonkit-n4sid": ["tendonkit.plugins.n4sid", "scipy.linalg", "threadpoolctl"],
        "tendonkit-arx": ["tendonkit", "scipy.linalg"],
        "sippy-n4sid": ["sippy_unipi", "sippy_unipi.OLSims_methods", "control.matlab"],
        "sippy-arx": ["sippy_unipi", "sippy_unipi.arxMIMO", "control.matlab"],
        "nfoursid": ["nfoursid.nfoursid", "pandas"],
    }[method]
    for name in modules:
        importlib.import_module(name)
    if method == "tendonkit-arx":
        import tendonkit as tk

        with contextlib.suppress(Exception):
            tk.identifiers()


def _worker(method: str, n: int, repeats: int, budget: float, result_path: str) -> None:
    """Subprocess body: identify (repeated while cheap), score, write JSON to ``result_path``."""
    out: dict[str, Any] = {"method": method, "N": n}
    try:
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    except (ImportError, ValueError, OSError):
        pass
    try:
        _warm_up(method)
        truth, data = _data(n, seed=1)
        _, valid = _data(N_VALID, seed=2)
        times: list[float] = []
        model = None
        start = time.perf_counter()
        while True:
            t0 = time.perf_counter()
            model = _identify(method, truth, data)
            times.append(time.perf_counter() - t0)
            spent = time.perf_counter() - start
            if len(times) >= repeats or times[-1] > REPEAT_BELOW or spent + times[-1] > budget / 2:
                break
        fit = _score(model, valid)
        rep = model.representation
        out.update(
            status="ok",
            times=times,
            time_s=statistics.median(times),
            fit=fit,
            fit_mean=sum(fit) / len(fit),
            n_states=int(rep.A.shape[0]) if rep.kind == "state_space" else None,
        )
    except MemoryError as exc:
        out.update(status="error", reason=f"MemoryError {exc}".strip())
    except Exception as exc:
        reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        out.update(status="error" if not _missing(exc) else "skipped", reason=reason)
    Path(result_path).write_text(json.dumps(out))


def _missing(exc: Exception) -> bool:
    """An unavailable method (peer not installed, tendonkit plugin not registered yet)."""
    from tendonkit.errors import PluginError

    return isinstance(exc, ImportError | PluginError)


def run(method: str, n: int, *, timeout: float, repeats: int) -> dict[str, Any]:
    """Run one (method, N) in a subprocess with ``timeout`` seconds; never raises."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "result.json")
        cmd = [
            sys.executable,
            __file__,
            "--worker",
            method,
            str(n),
            str(repeats),
            str(timeout),
            path,
        ]
        t0 = time.perf_counter()
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"method": method, "N": n, "status": "timeout", "reason": f"> {timeout:g} s"}
        if os.path.exists(path):
            return dict(json.loads(Path(path).read_text()))
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["no output"]
        return {
            "method": method,
            "N": n,
            "status": "error",
            "reason": f"worker exited {proc.returncode} after {time.perf_counter() - t0:.0f} s: {tail[0][:300]}",
        }


def truth_fit() -> list[float]:
    """The true system's own fit on the validation record (the noise ceiling)."""
    truth, valid = _data(N_VALID, seed=2)
    return _score(truth, valid)


def machine() -> dict[str, Any]:
    """CPU model, core count and library versions."""
    from importlib import metadata

    cpu = platform.processor() or "unknown"
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    versions = {}
    for pkg in ("tendonkit", "numpy", "scipy", "sippy_unipi", "nfoursid"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = "not installed"
    return {
        "load_average": list(os.getloadavg()),
        "cpu": cpu,
        "nproc": os.cpu_count(),
        "python": platform.python_version(),
        "versions": versions,
    }


def _label_n(n: int) -> str:
    return f"{n // 1000}k" if n % 1000 == 0 else str(n)


def markdown(results: list[dict[str, Any]], ceiling: float, sizes: list[int]) -> str:
    """Results as a markdown table: time and validation fit per method and size."""
    head = "| method | " + " | ".join(f"N={_label_n(n)}: time [s] | fit [%]" for n in sizes) + " |"
    sep = "|---|" + "---:|---:|" * len(sizes)
    lines = [head, sep]
    by_key = {(r["method"], r["N"]): r for r in results}
    for key, label in METHODS.items():
        if not any(r["method"] == key for r in results):
            continue
        cells = []
        for n in sizes:
            r = by_key.get((key, n))
            if r is None:
                cells += ["–", "–"]
            elif r["status"] == "ok":
                cells += [f"{r['time_s']:.3g}", f"{r['fit_mean']:.3f}"]
            else:
                cells += [r["status"], "–"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append(
        "| true system (noise ceiling) | " + " | ".join(f"– | {ceiling:.3f}" for _ in sizes) + " |"
    )
    ratios = []
    for n in sizes:
        ours, peer = by_key.get(("tendonkit-n4sid", n)), by_key.get(("sippy-n4sid", n))
        if ours and peer and ours["status"] == "ok" and peer["status"] == "ok":
            ratios.append(f"N={_label_n(n)} ×{peer['time_s'] / ours['time_s']:.0f}")
    if ratios:
        lines += ["", "tendonkit n4sid speed-up over SIPPY N4SID: " + ", ".join(ratios) + "."]
    notes = [
        f"- {METHODS[r['method']]} at N={_label_n(r['N'])}: {r['status']} ({r.get('reason', '')})"
        for r in results
        if r["status"] != "ok"
    ]
    return "\n".join(lines + (["", *notes] if notes else []))


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--worker":
        _worker(argv[1], int(argv[2]), int(argv[3]), float(argv[4]), argv[5])
        return 0
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="2000,20000,200000", help="training sizes, comma-separated")
    p.add_argument("--methods", default=",".join(METHODS), help="methods, comma-separated")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per method and size")
    p.add_argument("--repeats", type=int, default=5, help="repeats of runs under 10 s (median)")
    p.add_argument("--out", default="results.json", help="JSON file for the raw results")
    args = p.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    methods = [m for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        p.error(f"unknown methods {unknown}; choose from {list(METHODS)}")
    ceiling = truth_fit()
    load_before = list(os.getloadavg())
    results = []
    for n in sizes:
        for method in methods:
            r = run(method, n, timeout=args.timeout, repeats=args.repeats)
            results.append(r)
            shown = (
                f"{r['time_s']:.3f} s, fit {r['fit_mean']:.3f} %"
                if r["status"] == "ok"
                else f"{r['status']}: {r.get('reason', '')}"
            )
            print(f"N={n:>7} {method:<16} {shown}", file=sys.stderr, flush=True)
    report = {
        "machine": {**machine(), "load_average_before": load_before},
        "config": {
            "system": "random_state_space(8, 4, 2, seed=0)",
            "noise": NOISE,
            "train_seed": 1,
            "valid_seed": 2,
            "n_valid": N_VALID,
            "timeout_s": args.timeout,
            "memory_limit_bytes": MEMORY_LIMIT,
            "sizes": sizes,
        },
        "truth_fit": ceiling,
        "truth_fit_mean": sum(ceiling) / len(ceiling),
        "results": results,
    }
    Path(args.out).write_text(json.dumps(report, indent=1))
    print(markdown(results, sum(ceiling) / len(ceiling), sizes))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
