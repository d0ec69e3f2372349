"""tendonkit's linear models on six real benchmarks, official splits, default options (issue 17).

Run from the repository root, one BLAS thread (the README gives the command and results)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python benchmarks/bench_real.py --out r.json

Each dataset (../shared/data/real, splits and initialisation windows from its README) is
identified with ``n4sid``, ``arx`` and ``pem`` at their **default options** — nothing is set
per dataset except the split and the window — and scored in free-run simulation on the test
record(s): the initial state from the first ``init`` test samples
(``simulate(..., init_window=init)``), the RMSE on the samples after them, in the benchmark's
unit.  Bouc–Wen's protocol simulates the whole test record from the input alone; its test
record is one period of a multisine *in steady state* (its README), so the model's periodic
steady state is what is compared: the input period is simulated twice from a zero state and
the second pass scored (``init = "periodic"``).  A zero start (``"zero"``) adds the model's
own start-up transient to the error (reported beside it in the README).  The published best
linear and nonlinear results are printed beside.

The coupled drives' split pairs each record's training part (``[0:400]``) with its own test
part (``[400:500]``) and allows both training parts together; the official loader returns
them as two pairs.  The linear rows identify one model per record (``linear_cases()``) and
report the model fitted to both training parts beside them; ``diagnose`` (``--diagnose``)
uses both training parts together (a static curve is better seen over both amplitudes).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

import tendonkit as tk
from tendonkit.dataset import Dataset, Experiment
from tendonkit.parallel import run_tasks
from tendonkit.simulate import simulate

REAL = Path(os.environ.get("TENDONKIT_SHARED", Path(__file__).resolve().parents[2] / "shared"))
REAL = REAL / "data" / "real"

#: dataset -> (published best linear, published best nonlinear, unit label, unit factor)
PUBLISHED: dict[str, tuple[str, str, str, float]] = {
    "EMPS": ("5.53 (SS); ARX 12.6", "2.64 (dynoNet)", "mm", 1e3),
    "Silverbox multisine": ("6.95", "0.30 (GP-NARX)", "mV", 1e3),
    "Wiener-Hammerstein": ("43.4", "0.24 (SUBNET)", "mV", 1e3),
    "Cascaded tanks": ("0.588 (SS)", "0.34 (NLSS2)", "V", 1.0),
    "CED low": ("0.224", "0.096", "(z)", 1.0),
    "CED high": ("0.331", "0.074", "(z)", 1.0),
    "CED low, joint training": ("0.224", "0.096", "(z)", 1.0),
    "CED high, joint training": ("0.331", "0.074", "(z)", 1.0),
    "Bouc-Wen multisine": ("ARX(8,8) 1.5e-4", "1.9e-5 (PNLSS)", "m", 1.0),
    "Bouc-Wen multisine, zero start": ("ARX(8,8) 1.5e-4", "1.9e-5 (PNLSS)", "m", 1.0),
}


def _part(data: Dataset, start: int, stop: int, name: str) -> Experiment:
    """Samples ``start:stop`` of ``data``'s one experiment, time from zero."""
    e = data.experiments[0]
    s = slice(start, stop)
    return Experiment(t=e.t[s] - e.t[start], u=e.u[s], y=e.y[s], name=name)


def _slice(data: Dataset, start: int, stop: int, name: str) -> Dataset:
    return data.with_experiments([_part(data, start, stop, name)])


def cases() -> list[tuple[str, Dataset, list[tuple[str, Dataset, int | str]]]]:
    """``(dataset, train, [(test name, test, init window, "zero" or "periodic")])``."""
    out = []
    emps = REAL / "emps"
    out.append(
        (
            "EMPS",
            Dataset.from_csv(emps / "emps_train.csv", ["u_vir"], ["y_qm"]),
            [("EMPS", Dataset.from_csv(emps / "emps_test.csv", ["u_vir"], ["y_qm"]), 20)],
        )
    )
    sb = Dataset.from_csv(REAL / "silverbox" / "silverbox_SNLS80mV.csv", ["u"], ["y"])
    out.append(
        (
            "Silverbox",
            _slice(sb, 40650, 105712, "train"),
            [("Silverbox multisine", _slice(sb, 105712, 127400, "test"), 50)],
        )
    )
    wh = Dataset.from_csv(REAL / "wiener_hammerstein" / "wh2009_full.csv", ["u"], ["y"])
    out.append(
        (
            "Wiener-Hammerstein",
            _slice(wh, 5200, 105200, "train"),
            [("Wiener-Hammerstein", _slice(wh, 105200, 184000, "test"), 50)],
        )
    )
    tanks = REAL / "cascaded_tanks"
    out.append(
        (
            "Cascaded tanks",
            Dataset.from_csv(tanks / "cascaded_tanks_train.csv", ["u"], ["y"]),
            [
                (
                    "Cascaded tanks",
                    Dataset.from_csv(tanks / "cascaded_tanks_test.csv", ["u"], ["y"]),
                    50,
                )
            ],
        )
    )
    ced = {
        k: Dataset.from_csv(REAL / "coupled_electric_drives" / "ced_unif.csv", [u], [z])
        for k, (u, z) in {"low": ("u11", "z11"), "high": ("u12", "z12")}.items()
    }

    train = Dataset(
        inputs=("u",), outputs=("z",), dt=ced["low"].dt,
        experiments=(_part(ced["low"], 0, 400, "low"), _part(ced["high"], 0, 400, "high")),
    )  # fmt: skip
    tests = [
        (
            f"CED {k}",
            Dataset(inputs=("u",), outputs=("z",), dt=d.dt, experiments=(_part(d, 400, 500, k),)),
            10,
        )
        for k, d in ced.items()
    ]
    out.append(("Coupled electric drives", train, tests))
    bw = REAL / "bouc_wen"
    bw_test = Dataset.from_csv(bw / "boucwen_test_multisine.csv", ["u"], ["y"])
    out.append(
        (
            "Bouc-Wen",
            Dataset.from_csv(bw / "boucwen_train_multisine_generated.csv", ["u"], ["y"]),
            [
                ("Bouc-Wen multisine", bw_test, "periodic"),
                ("Bouc-Wen multisine, zero start", bw_test, "zero"),
            ],
        )
    )
    return out


def rmse(model: tk.schema.Model, test: Dataset, init: int | str) -> float:
    errors = []
    for e in test.experiments:
        if init == "zero":
            sim = simulate(model, e.u, initial="zero")
            errors.append(e.y - sim)
        elif init == "periodic":  # steady state: the second of two periods from zero
            n = e.u.shape[0]
            sim = simulate(model, np.vstack([e.u, e.u]), initial="zero")[n:]
            errors.append(e.y - sim)
        else:
            assert isinstance(init, int)
            sim = simulate(model, e.u, y=e.y, initial="estimate", init_window=init)
            errors.append(e.y[init:] - sim[init:])
    err = np.vstack(errors)
    return float(np.sqrt(np.mean(err**2)))


def split_training(train: Dataset, share: float = 0.25) -> tuple[Dataset, Dataset]:
    """The training record cut in two: the first ``1 - share`` to fit, the rest to validate.

    ``diagnose`` needs validation data to test its findings; the official test record must not
    be it (the test would then choose the model it scores), so the diagnosis runs inside the
    training data and the extended model is scored on the test record like any other.
    """
    fit_parts, check_parts = [], []
    for e in train.experiments:
        cut = round((1.0 - share) * e.n_samples)
        fit_parts.append(_part(train.with_experiments([e]), 0, cut, f"{e.name}:fit"))
        check_parts.append(_part(train.with_experiments([e]), cut, e.n_samples, f"{e.name}:check"))
    return train.with_experiments(fit_parts), train.with_experiments(check_parts)


def linear_cases() -> list[tuple[str, Dataset, list[tuple[str, Dataset, int | str]]]]:
    """The cases of the linear rows: ``cases()`` with the coupled drives one model per record.

    Each record's own 400 training samples for its own test (the split's pairs), then the
    model fitted to both training parts, scored on both tests as "CED …, joint training".
    """
    out = []
    for name, train, tests in cases():
        if name != "Coupled electric drives":
            out.append((name, train, tests))
            continue
        for e, test in zip(train.experiments, tests, strict=True):
            out.append((f"{name} ({e.name})", train.with_experiments([e]), [test]))
        joint = [(f"{t}, joint training", data, init) for t, data, init in tests]
        out.append((f"{name} (joint training)", train, joint))
    return out


# The datasets, read once per process (workers read them too: nothing is sent).
_cases = functools.cache(cases)
_linear_cases = functools.cache(linear_cases)


def diagnose_task(_shared: Any, index: int) -> list[dict[str, Any]]:
    """``diagnose`` at default options on one dataset; its final model scored on the tests."""
    from tendonkit.diagnose import diagnose

    _dataset, train, tests = _cases()[index]
    fit_data, check = split_training(train)
    t0 = time.perf_counter()
    d = diagnose(fit_data, check)
    seconds = time.perf_counter() - t0
    rows = []
    for name, test, init in tests:
        linear, nonlinear, unit, factor = PUBLISHED[name]
        base = rmse(d.baseline, test, init) * factor
        ext = rmse(d.extended, test, init) * factor
        rows.append(
            {
                "test": name, "method": "diagnose", "causes": list(d.causes),
                "baseline_rmse": base, "rmse": ext, "unit": unit, "init_window": init,
                "seconds": seconds, "published_linear": linear,
                "published_nonlinear": nonlinear,
                "steps": [
                    {"cause": st.cause, "gain": st.gain, "p_adjusted": st.p_adjusted}
                    for st in d.steps
                ],
            }
        )  # fmt: skip
    return rows


def identify_task(_shared: Any, job: tuple[int, str]) -> list[dict[str, Any]]:
    """One method on one dataset at default options, scored on the dataset's tests."""
    index, method = job
    _dataset, train, tests = _linear_cases()[index]
    t0 = time.perf_counter()
    try:
        model = tk.identify(train, method)
        error = None
    except tk.errors.TendonkitError as exc:
        model, error = None, str(exc)
    seconds = time.perf_counter() - t0
    rows = []
    for name, test, init in tests:
        linear, nonlinear, unit, factor = PUBLISHED[name]
        value = rmse(model, test, init) * factor if model is not None else None
        rows.append(
            {
                "test": name, "method": method, "rmse": value, "unit": unit,
                "notes": model.provenance.notes if model is not None else None,
                "init_window": init, "identify_s": seconds, "error": error,
                "published_linear": linear, "published_nonlinear": nonlinear,
            }
        )  # fmt: skip
    return rows


def _show(row: dict[str, Any]) -> None:
    linear, nonlinear, unit = row["published_linear"], row["published_nonlinear"], row["unit"]
    if row["method"] == "diagnose":
        print(
            f"{row['test']:22s} diagnose causes {', '.join(row['causes'])}: RMSE baseline "
            f"{row['baseline_rmse']:.4g} -> extended {row['rmse']:.4g} {unit} (published "
            f"nonlinear {nonlinear}); {row['seconds']:.0f} s"
        )
        return
    shown = f"{row['rmse']:.4g}" if row["rmse"] is not None else f"failed: {row['error']}"
    print(
        f"{row['test']:22s} {row['method']:6s} RMSE {shown} {unit} (published linear {linear}, "
        f"nonlinear {nonlinear}); identify {row['identify_s']:.1f} s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default=None, help="JSON file for the results")
    parser.add_argument("--methods", default="n4sid,arx,pem", help="identifiers, comma separated")
    parser.add_argument(
        "--diagnose",
        action="store_true",
        help="run diagnose at default options instead (diagnosis inside the training record, "
        "the final extended model scored on the test records)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="worker processes, one dataset x method each (tendonkit.parallel; default 1)",
    )
    parser.add_argument("--scheduler", help="a dask scheduler address, or 'local'")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    if args.diagnose:
        fn, jobs = diagnose_task, list(range(len(_cases())))
    else:
        n = len(_linear_cases())
        fn, jobs = identify_task, [(i, m) for i in range(n) for m in args.methods.split(",")]
    results: list[list[dict[str, Any]]] = [[] for _ in jobs]
    t0 = time.perf_counter()
    for o in run_tasks(fn, jobs, jobs=args.jobs, scheduler=args.scheduler):
        if o.error is not None:
            raise SystemExit(f"{jobs[o.index]} failed: {o.error}")
        results[o.index] = o.value
        for row in o.value:
            _show(row)
    rows = [r for part in results for r in part]
    if args.out:
        machine = {
            "load_before": load,
            "load_after": os.getloadavg()[0],
            "jobs": args.jobs,
            "scheduler": args.scheduler,
            "wall_s": time.perf_counter() - t0,
        }
        Path(args.out).write_text(json.dumps({"rows": rows, "machine": machine}, indent=1))


if __name__ == "__main__":
    main()
