"""Subcommands on models and data: ``identify``, ``simulate`` and ``compare``."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from ..compare import compare, render_compare
from ..dataset import Dataset, dependent_inputs, write_csv
from ..errors import DataError, SimulationError
from ..identification import poor_fit_warning
from ..predict import predict
from ..preprocess import lowpass, paper_cutoff_hz
from ..robot.reconstruct import has_base_joints, joint_extras
from ..simulate import check_sample_time, check_units, divergence, simulate
from .common import (
    atomic_write,
    check_output_dir,
    check_output_path,
    csv_header,
    identifier_arguments,
    load_model,
    noted,
    output_dirs,
    raise_problems,
    same_file,
    warn,
    write_json,
)


def add_commands(sub: Any) -> None:
    """Add ``identify``, ``simulate`` and ``compare`` to the ``tendonkit`` subparsers."""
    p = sub.add_parser("identify", help="identify a model from CSV data")
    p.add_argument("data", nargs="+", help="CSV file(s); several files are several experiments")
    p.add_argument("--method", default="arx", help="identifier name (see 'tendonkit plugins')")
    p.add_argument("--inputs", required=True, help="input columns, comma separated")
    p.add_argument("--outputs", required=True, help="output columns, comma separated")
    p.add_argument("--option", action="append", metavar="KEY=VALUE", help="identifier option")
    p.add_argument("-o", "--output", required=True, help="model JSON file to write")
    p.add_argument("--time", default="t", help="time column in seconds (default: t)")
    p.add_argument(
        "--units",
        metavar="NAME=UNIT,...",
        help="units of inputs and outputs whose CSV header does not give them (a header cell "
        "'q1 [rad]' does); they are stored in the model and checked against data it meets",
    )
    p.add_argument("--json", help="also write a JSON summary here")
    p.add_argument(
        "--lowpass",
        metavar="HZ|paper|paper-matlab",
        help="zero-phase low-pass of the outputs before identifying: a cut-off in Hz, or the "
        "paper's 0.001 rad/sample read literally ('paper') or as MATLAB does ('paper-matlab')",
    )
    p.set_defaults(func=cmd_identify)

    p = sub.add_parser("simulate", help="simulate a model on the inputs of a CSV file")
    p.add_argument("model", help="model JSON file")
    p.add_argument(
        "data", help="CSV file with the model's inputs (and outputs for --initial estimate)"
    )
    p.add_argument("-o", "--output", required=True, help="CSV file to write (t and model outputs)")
    p.add_argument(
        "--initial",
        choices=["zero", "model", "estimate"],
        help="initial state: zero, the model's x0, or estimated from the measured outputs "
        "(default: estimate when the outputs are in the data, else model)",
    )
    p.add_argument("--k", type=int, help="k-step-ahead prediction instead of free run")
    p.add_argument("--time", default="t", help="time column (default: t)")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("compare", help="fit of models on data (the paper's Table I)")
    p.add_argument("files", nargs="+", help="DATA.csv and one or more MODEL.json")
    p.add_argument("--json", help="write the results as JSON here")
    p.add_argument("--initial", default="estimate", choices=["zero", "model", "estimate"])
    p.add_argument("--k", type=int, help="score k-step-ahead prediction instead of free run")
    p.add_argument(
        "--init-window",
        type=int,
        metavar="N",
        help="benchmark protocol: the initial state from the first N samples of each "
        "experiment only (with --initial estimate), fit and RMSE on the samples after them",
    )
    p.add_argument("--joints", action="store_true", help="also reconstruct q3..q6 and score them")
    p.add_argument("--ee", action="store_true", help="also score the end-effector error (cm)")
    p.add_argument("--plot", help="write figures (PNG) into this folder")
    p.add_argument("--time", default="t", help="time column (default: t)")
    p.set_defaults(func=cmd_compare)


def cmd_identify(args: argparse.Namespace) -> int:
    """Identify a model from CSV data with a registered method."""
    problems: list[str] = []
    inputs, outputs, _, factory = identifier_arguments(args, problems)
    check_output_path(args.output, args.data, problems)
    if args.json:
        check_output_path(args.json, args.data, problems, what="--json")
        if same_file(args.json, args.output):
            problems.append(
                "-o and --json name the same file; the summary would replace the model."
            )
    data = None
    units = _units_argument(args.units, problems)
    try:
        data = Dataset.from_csv(args.data, inputs, outputs, time=args.time, units=units)
    except DataError as exc:
        problems.extend(exc.problems or [str(exc)])
    cutoff = _lowpass_cutoff(args.lowpass, data, problems) if args.lowpass else None
    raise_problems(problems, "tendonkit identify cannot run:")
    assert data is not None and factory is not None
    if cutoff is not None:
        data = lowpass(data, cutoff)
    model = factory.identify(data)
    # the model is named after its file (FMUs exported from it carry the name)
    model = model.replace(name=Path(args.output).stem or model.name)
    if cutoff is not None:
        model = noted(model, f"outputs low-pass filtered at {cutoff:.6g} Hz (zero-phase)")
    atomic_write(args.output, model.save)
    said = [w for w in (dependent_inputs(data), poor_fit_warning(model)) if w]
    summary = {
        "model": str(args.output),
        "method": args.method,
        "kind": model.kind,
        "training_fit": model.provenance.training_fit,
        "samples": data.n_samples,
        "lowpass_hz": cutoff,
        "warnings": said,
    }
    if args.json:
        write_json(args.json, summary)
    fits = ", ".join(f"{k} {v:.2f} %" for k, v in model.provenance.training_fit.items())
    print(f"{args.method}: {model.kind} model written to {args.output} (training fit: {fits})")
    for w in said:
        warn(w)
    return 0


def _units_argument(value: str | None, problems: list[str]) -> dict[str, str]:
    """``--units q1=rad,T1=N``: a unit per signal name."""
    units: dict[str, str] = {}
    for item in (value or "").split(","):
        if not item.strip() and value is None:
            continue
        name, eq, unit = item.partition("=")
        if not eq or not name.strip() or not unit.strip():
            problems.append(f"--units takes NAME=UNIT pairs separated by commas, found {item!r}.")
            continue
        if name.strip() in units:
            problems.append(f"--units gives {name.strip()!r} twice.")
        units[name.strip()] = unit.strip()
    return units


def _lowpass_cutoff(value: str, data: Any, problems: list[str]) -> float | None:
    """``--lowpass``: a cut-off in Hz, or ``paper`` / ``paper-matlab`` (the paper's filter)."""
    if data is None:
        return None
    nyquist = 0.5 / data.dt
    if value in ("paper", "paper-matlab"):
        return float(paper_cutoff_hz(data.dt, "literal" if value == "paper" else "matlab"))
    try:
        hz = float(value)
    except ValueError:
        problems.append(
            f"--lowpass must be a cut-off in Hz, 'paper' or 'paper-matlab', found {value!r}."
        )
        return None
    if not (math.isfinite(hz) and 0 < hz < nyquist):
        problems.append(
            f"--lowpass must be between 0 and the Nyquist frequency {nyquist:.6g} Hz, found {value}."
        )
        return None
    return hz


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate a model on the inputs of a CSV file and write its outputs as CSV."""
    problems: list[str] = []
    model = load_model(args.model, problems)
    check_output_path(args.output, [args.model, args.data], problems)
    if args.k is not None and args.k < 1:
        problems.append(f"--k must be >= 1, found {args.k}.")
    data = None
    if model is not None:
        header = csv_header(args.data)
        have_y = all(n in header for n in model.output_names)
        initial = args.initial or ("estimate" if have_y else "model")
        if initial == "estimate" and not have_y:
            problems.append(
                "--initial estimate needs the model's outputs "
                f"({', '.join(model.output_names)}) in {args.data}."
            )
        if args.k is not None and not have_y:
            problems.append(f"--k needs the measured outputs ({', '.join(model.output_names)}).")
        try:
            data = Dataset.from_csv(
                args.data,
                model.input_names,
                model.output_names if have_y else [],
                time=args.time,
                require_outputs=False,
            )
        except DataError as exc:
            problems.extend(exc.problems or [str(exc)])
    if data is not None and model is not None:
        try:
            check_sample_time(model, data.dt, what=f"{args.data!r}")
        except DataError as exc:
            problems.append(str(exc))
        try:
            check_units(model, data.units, what=f"{args.data!r}")
        except DataError as exc:
            problems.append(str(exc).replace("\n", "\n   "))
    if data is not None and args.k is not None and args.k > data.n_samples:
        problems.append(
            f"--k must be at most the number of samples ({data.n_samples}), found {args.k}."
        )
    raise_problems(problems, "tendonkit simulate cannot run:")
    assert model is not None and data is not None
    exp = data.experiments[0]
    y_meas = exp.y if exp.y.shape[1] else None
    if args.k is not None:
        assert y_meas is not None
        y = predict(model, exp.u, y_meas, k=args.k)
    else:
        y = simulate(model, exp.u, y=y_meas, initial=initial)  # type: ignore[arg-type]
    reference = y_meas if y_meas is not None else y[: max(10, len(y) // 10)]
    k = divergence(y, reference)
    if k is not None:
        raise SimulationError(
            f"The simulation of model {model.name!r} diverged at sample {k} (t = {exp.t[k]:g} s): "
            "its outputs left 10^6 times the range of "
            + ("the measured outputs" if y_meas is not None else "their first tenth")
            + "; the model is unstable on these inputs. Nothing was written."
        )
    cols = {args.time: exp.t, **{n: y[:, j] for j, n in enumerate(model.output_names)}}
    units = {s.name: s.unit for s in model.outputs}  # the time column is named as in DATA
    atomic_write(args.output, lambda p: write_csv(p, cols, units))
    what = f"{args.k}-step prediction" if args.k else f"free-run simulation (initial: {initial})"
    print(f"{what} of {len(exp.t)} samples written to {args.output}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    """Fit of one or more models on data: the paper's Table I."""
    problems: list[str] = []
    data_files = [f for f in args.files if f.lower().endswith(".csv")]
    model_files = [f for f in args.files if not f.lower().endswith(".csv")]
    if not data_files:
        problems.append("no data file (.csv) given.")
    if not model_files:
        problems.append("no model file (.json) given.")
    loaded = [load_model(f, problems) for f in model_files]
    models = [m for m in loaded if m is not None]
    if args.k is not None and args.k < 1:
        problems.append(f"--k must be >= 1, found {args.k}.")
    if args.init_window is not None:
        if args.init_window < 1:
            problems.append(f"--init-window must be >= 1, found {args.init_window}.")
        if args.k is not None:
            problems.append("--init-window applies to free-run simulation, not to --k.")
        if args.initial != "estimate":
            problems.append("--init-window needs --initial estimate (the state is estimated).")
    if args.json:
        check_output_path(args.json, args.files, problems, what="--json")
    if args.plot:
        check_output_dir(args.plot, args.files, problems, what="--plot")
    if args.json and args.plot and same_file(args.json, args.plot):
        problems.append("--json and --plot name the same path.")
    datasets: dict[tuple[tuple[str, ...], tuple[str, ...]], Dataset] = {}
    for m in models if data_files else []:
        key = (tuple(m.input_names), tuple(m.output_names))
        if key in datasets:
            continue
        try:
            datasets[key] = Dataset.from_csv(data_files, *key, time=args.time)
        except DataError as exc:
            problems.extend(f"model {m.name!r}: {q}" for q in (exc.problems or [str(exc)]))
    shortest = min((d.n_samples for d in datasets.values()), default=None)
    if args.k is not None and shortest is not None and args.k > shortest:
        problems.append(f"--k must be at most the number of samples ({shortest}), found {args.k}.")
    short = min((len(e.y) for d in datasets.values() for e in d.experiments), default=None)
    if args.init_window and short is not None and args.init_window >= short:
        problems.append(
            f"--init-window {args.init_window} leaves nothing to score: the shortest experiment "
            f"has {short} samples."
        )
    raise_problems(problems, "tendonkit compare cannot run:")
    # The robot's joints: asked for with --joints/--ee; drawn with --plot when every model has
    # the base joints q1, q2 (other models get the measured-vs-simulated figure only).
    robot_plots = bool(args.plot) and all(has_base_joints(m) for m in models)
    extras = (
        joint_extras(joints=args.joints, ee=args.ee, plot_dir=args.plot)
        if args.joints or args.ee or robot_plots
        else None
    )
    with output_dirs(args.plot):
        result = compare(
            models,
            next(iter(datasets.values())) if len(datasets) == 1 else data_files,
            names=model_files,
            initial=args.initial,
            k=args.k,
            time=args.time,
            init_window=args.init_window,
            plot_dir=args.plot,
            extras=extras,
        )
    print(render_compare(result))
    if args.json:
        write_json(args.json, result)
    return 0
