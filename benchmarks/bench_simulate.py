"""Simulation speed: the compiled kernel against the numpy reference and peers (issue 16).

Run from the repository root, one BLAS thread (the README gives the command and results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_simulate.py --out r.json

Sections:

1. free-run throughput in samples/s of every representation, ``engine="compiled"`` against
   ``engine="reference"`` (and ``scipy.signal.dlsim`` for the linear state space);
2. identification at 200k samples including the training-fit simulation: tendonkit's SINDYc
   against pysindy's fit with the same library and threshold, tendonkit's ARX against a plain
   numpy least-squares MIMO ARX;
3. ``diagnose`` on the demo's data (paper-like plant, the demo's protocols) with the SINDYc
   baseline, the whole workflow on either engine (``tendonkit.simulate.ENGINE``).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tendonkit import identify
from tendonkit.dataset import Dataset
from tendonkit.schema import Model, Signal, SparseMap, StateSpace
from tendonkit.terms import Factor, Term
from tendonkit.testsystems import random_state_space, simulate_truth

#: The module (``tendonkit.simulate`` as an attribute is the function of that name).
sim = importlib.import_module("tendonkit.simulate")


def best_of(fn: Callable[[], Any], repeat: int = 3) -> float:
    """Smallest wall time of ``repeat`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def _models(rng: np.random.Generator) -> dict[str, Model]:
    ins = tuple(Signal(f"u{i}") for i in range(1, 5))
    outs = (Signal("y1"), Signal("y2"))
    truth = random_state_space(8, 4, 2, seed=0)
    ss = truth.representation
    assert isinstance(ss, StateSpace)
    data = simulate_truth(truth, 5000, noise=0.01, seed=1)[0]
    arx = identify(data, "arx")  # na = nb = 8
    bil = identify(data, "arx", na=3, nb=3, bilinear=True)
    # The paper's SINDYc library: 2 states, 4 inputs, monomials to degree 2 and sin of the
    # states (30 terms), every coefficient nonzero (a dense map: the worst case).
    names = ["x1", "x2", "u1", "u2", "u3", "u4"]
    terms: list[Term] = [Term(())]
    terms += [Term((Factor(n),)) for n in names]
    terms += [Term((Factor(a), Factor(b))) for i, a in enumerate(names) for b in names[i:]]
    terms += [Term((Factor("x1", fn="sin"),)), Term((Factor("x2", fn="sin"),))]
    coef = rng.normal(0, 1e-4, (len(terms), 2))
    coef[1:3] = np.diag([0.9, 0.8])
    sparse = Model(
        "sindyc_library",
        0.03,
        ins,
        outs,
        SparseMap(tuple(terms), coef, (0, 1)),
        states=(Signal("x1"), Signal("x2")),
    )
    # Polynomial terms of the past outputs (a stiffness extension: y³ and y⁵ of both outputs
    # at lags 1-4, 16 terms), the ARX (8, 8, 1) refitted with them.
    from tendonkit.diagnose import extend_with_terms

    poly = [
        Term((Factor(n, power=p, lag=k, scale=1.0 / float(data.y[:, j].std())),))
        for j, n in enumerate(("y1", "y2"))
        for p in (3, 5)
        for k in range(1, 5)
    ]
    cubic = extend_with_terms(arx, data, poly)
    return {
        "state_space (order 8)": truth,
        "arx (na = nb = 8)": arx,
        "arx bilinear (na = nb = 3, 8 u·y terms)": bil,
        "arx (na = nb = 8) with 16 terms y³, y⁵": cubic,
        f"sparse_map (SINDYc library, {len(terms)} terms)": sparse,
    }


def throughput(n: int, n_reference: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(0)
    rows = []
    for name, model in _models(rng).items():
        u = rng.normal(0, 1, (n, 4)) * (0.1 if "sparse" in name else 1.0)
        row: dict[str, Any] = {"model": name, "samples": n}
        for engine, m in (("compiled", n), ("reference", n_reference)):
            t = best_of(
                lambda e=engine, m=m, model=model, u=u: sim.simulate(
                    model, u[:m], initial="zero", engine=e
                )
            )
            row[f"{engine}_samples_per_s"] = m / t
        # a diverged run stops early (NaN from there on) and would time too well
        row["finite"] = bool(np.isfinite(sim.simulate(model, u, initial="zero")).all())
        if isinstance(model.representation, StateSpace):
            # lazy: a peer
            from scipy.signal import dlsim

            r = model.representation
            t = best_of(lambda r=r, dt=model.dt, u=u: dlsim((r.A, r.B, r.C, r.D, dt), u), 1)
            row["scipy_dlsim_samples_per_s"] = n / t
        rows.append(row)
        print(json.dumps(row))
    return rows


def _robot_data(seconds: float, seed: int) -> Dataset:
    from tendonkit.fmu.plant import Plant, PlantConfig
    from tendonkit.robot.protocol import pseudo_random

    plant = Plant(PlantConfig.preset("paper_like").replace(noise_on=True, seed=seed))
    plant.reset()
    log = plant.record(pseudo_random(duration=seconds, seed=seed).u)
    return Dataset.from_arrays(
        log["T_meas"], log["q"][:, :2], dt=0.03, inputs=("T1", "T2", "T3", "T4"),
        outputs=("q1", "q2"),
    )  # fmt: skip


def identification(n: int) -> list[dict[str, Any]]:
    import pysindy as ps

    rows = []
    data = _robot_data(n * 0.03, 1)
    # SINDYc: tendonkit (the training fit included) and pysindy's fit on the same library,
    # normalisation and threshold (the threshold tendonkit's sweep chose, given explicitly).
    model = identify(data, "sindyc")
    lam = float(model.provenance.details["threshold"])
    t_tk = best_of(lambda: identify(data, "sindyc", threshold=lam))
    from tendonkit.plugins.sindyc import _library, _Normalisation

    norm = _Normalisation.of(data, True)
    xs = [norm.states(e.y) for e in data.experiments]
    us = [norm.inputs(e.u) for e in data.experiments]

    def pysindy_fit() -> None:
        # what tendonkit's sindyc calls (plugins/sindyc.py, _pysindy_fit), alone
        ps.DiscreteSINDy(
            optimizer=ps.STLSQ(threshold=lam, alpha=0.05, max_iter=20),
            feature_library=_library(2, 4, 2, True),
        ).fit(xs, t=0.03, u=us)

    t_ps = best_of(pysindy_fit)
    rows.append({"what": f"SINDYc fit, {n} samples", "tendonkit_s": t_tk, "pysindy_s": t_ps})
    print(json.dumps(rows[-1]))

    # ARX na = nb = 8, nk = 1: tendonkit (training fit included) and plain numpy lstsq.
    def numpy_arx_vectorised() -> None:
        y, u = data.y, data.u
        na = nb = 8
        n_ = len(y)
        cols = [-y[na - i : n_ - i] for i in range(1, na + 1)]
        cols += [u[na - i : n_ - i] for i in range(1, nb + 1)]
        phi = np.hstack(cols)
        np.linalg.lstsq(phi, y[na:], rcond=None)

    t_arx = best_of(lambda: identify(data, "arx"))
    t_np = best_of(numpy_arx_vectorised)
    rows.append(
        {"what": f"ARX (8, 8, 1) fit, {n} samples", "tendonkit_s": t_arx, "numpy_lstsq_s": t_np}
    )
    print(json.dumps(rows[-1]))
    return rows


def diagnosis() -> dict[str, Any]:
    """``diagnose`` with the SINDYc baseline on the demo's data, on either engine."""
    from tendonkit.diagnose import diagnose
    from tendonkit.fmu.plant import Plant, PlantConfig
    from tendonkit.robot.study import INPUTS, OUTPUTS, _protocols

    cfg = PlantConfig.preset("paper_like").replace(noise_on=True, seed=1)
    parts = {}
    for i, (name, prot) in enumerate(_protocols(False, 1).items()):
        plant = Plant(cfg.replace(seed=1 + i))
        plant.reset()
        log = plant.record(prot.u)
        parts[name] = Dataset.from_arrays(
            log["T_meas"], log["q"][:, :2], dt=0.03, inputs=INPUTS, outputs=OUTPUTS, name=name
        )
    train = parts["train_circles"].concat(parts["train_random"])
    valid = parts["valid_random"].concat(parts["valid_circles"])
    model = identify(train, "sindyc")
    options = {"threshold": model.provenance.details["threshold"]}
    out: dict[str, Any] = {"train_samples": train.n_samples, "valid_samples": valid.n_samples}
    for engine in ("compiled", "reference"):
        sim.ENGINE = engine
        t = time.perf_counter()
        d = diagnose(train, valid, method="sindyc", options=options)
        out[f"{engine}_s"] = time.perf_counter() - t
        out[f"{engine}_cause"] = d.cause
        print(json.dumps(out))
    sim.ENGINE = "compiled"
    out["speed_up"] = out["reference_s"] / out["compiled_s"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--reference-samples", type=int, default=20_000)
    ap.add_argument("--fit-samples", type=int, default=200_000)
    ap.add_argument("--skip-diagnose", action="store_true")
    ap.add_argument("--out", default="bench_simulate.json")
    args = ap.parse_args()
    load = os.getloadavg()
    result: dict[str, Any] = {
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "load_before": load,
            "omp_threads": os.environ.get("OMP_NUM_THREADS"),
        }
    }
    result["throughput"] = throughput(args.samples, args.reference_samples)
    result["identification"] = identification(args.fit_samples)
    if not args.skip_diagnose:
        result["diagnose"] = diagnosis()
    result["machine"]["load_after"] = os.getloadavg()
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=1)
    print(json.dumps(result["machine"]))


if __name__ == "__main__":
    main()
