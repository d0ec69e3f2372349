"""The ``tendonkit`` command line: one subcommand per step of the data flow.

Every user error (arguments, files, data, options) becomes one message that lists every problem
found, on standard error, with exit status 2 — never a traceback.  Heavy libraries are imported
inside the commands that need them, so ``tendonkit --help`` is instant.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import DataError, OptionError, TendonkitError

EXIT_USAGE = 2


class UsageError(TendonkitError, ValueError):
    """Command-line arguments that cannot work together."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors in tendonkit's one-message style (exit 2)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        print(f"tendonkit: error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


# -- helpers shared by commands ---------------------------------------------------------------


def split_names(text: str | None) -> list[str]:
    """``"a, b"`` -> ``["a", "b"]``."""
    return [p.strip() for p in (text or "").split(",") if p.strip()]


def parse_key_values(items: Sequence[str] | None, what: str, problems: list[str]) -> dict[str, str]:
    """Parse ``KEY=VALUE`` items, appending malformed ones to ``problems``."""
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            problems.append(f"{what} {item!r} is not of the form KEY=VALUE.")
            continue
        if key.strip() in out:
            problems.append(f"{what} {key.strip()!r} is given twice.")
        out[key.strip()] = value.strip()
    return out


def check_output_path(path: str | Path, inputs: Sequence[str | Path], problems: list[str]) -> None:
    """An output file must not be one of the inputs and its folder must exist."""
    out = Path(path).resolve()
    for src in inputs:
        if Path(src).resolve() == out:
            problems.append(f"output {str(path)!r} is also an input; refusing to overwrite it.")
    if not out.parent.exists():
        problems.append(f"the folder of output {str(path)!r} does not exist.")


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Write through a temporary file in the same folder, then rename (no partial files)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def write_json(path: str | Path, data: Any) -> Path:
    """Write JSON atomically."""
    return atomic_write(path, lambda p: p.write_text(json.dumps(data, indent=2), encoding="utf-8"))


def csv_header(path: str | Path) -> list[str]:
    """Column names of a CSV file (empty if unreadable; the loader reports why)."""
    import csv

    try:
        with Path(path).open(newline="", encoding="utf-8-sig") as fh:
            return [h.strip() for h in next(csv.reader(fh), [])]
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def raise_problems(problems: list[str], headline: str = "The command cannot run:") -> None:
    """Raise one :class:`UsageError` listing all problems, if any."""
    if problems:
        raise UsageError(headline, problems)


# -- identify / simulate / compare / plugins -------------------------------------------------------


def identifier_arguments(
    args: argparse.Namespace, problems: list[str]
) -> tuple[list[str], list[str], dict[str, str], Any]:
    """``--inputs``, ``--outputs``, ``--method`` and ``--option``: names, options, options object.

    Every problem is appended to ``problems``; the options object is None when the method or
    its options are invalid.
    """
    from ..manager import identifiers

    inputs, outputs = split_names(args.inputs), split_names(args.outputs)
    if not outputs:
        problems.append("--outputs names no column.")
    options = parse_key_values(args.option, "--option", problems)
    registry = identifiers()
    factory = None
    if args.method not in registry:
        problems.append(
            f"unknown method {args.method!r}; registered: {', '.join(registry.names())}."
        )
    else:
        try:
            factory = registry.get(args.method).create(**options)
        except OptionError as exc:
            problems.extend(exc.problems or [str(exc)])
    return inputs, outputs, options, factory


def cmd_identify(args: argparse.Namespace) -> int:
    """Identify a model from CSV data with a registered method."""
    from ..dataset import Dataset

    problems: list[str] = []
    inputs, outputs, _, factory = identifier_arguments(args, problems)
    check_output_path(args.output, args.data, problems)
    data = None
    try:
        data = Dataset.from_csv(args.data, inputs, outputs, time=args.time)
    except DataError as exc:
        problems.extend(exc.problems or [str(exc)])
    cutoff = _lowpass_cutoff(args.lowpass, data, problems) if args.lowpass else None
    raise_problems(problems, "tendonkit identify cannot run:")
    assert data is not None and factory is not None
    if cutoff is not None:
        from ..preprocess import lowpass

        data = lowpass(data, cutoff)
    model = factory.identify(data)
    if cutoff is not None:
        model = _noted(model, f"outputs low-pass filtered at {cutoff:.6g} Hz (zero-phase)")
    atomic_write(args.output, model.save)
    summary = {
        "model": str(args.output),
        "method": args.method,
        "kind": model.kind,
        "training_fit": model.provenance.training_fit,
        "samples": data.n_samples,
        "lowpass_hz": cutoff,
    }
    if args.json:
        write_json(args.json, summary)
    fits = ", ".join(f"{k} {v:.2f} %" for k, v in model.provenance.training_fit.items())
    print(f"{args.method}: {model.kind} model written to {args.output} (training fit: {fits})")
    return 0


def _lowpass_cutoff(value: str, data: Any, problems: list[str]) -> float | None:
    """``--lowpass``: a cut-off in Hz, or ``paper`` / ``paper-matlab`` (the paper's filter)."""
    from ..preprocess import paper_cutoff_hz

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


def _noted(model: Any, text: str) -> Any:
    """``model`` with ``text`` appended to its provenance notes."""
    import dataclasses

    prov = model.provenance
    notes = f"{prov.notes}; {text}" if prov.notes else text
    return model.replace(provenance=dataclasses.replace(prov, notes=notes))


def cmd_simulate(args: argparse.Namespace) -> int:
    """Simulate a model on the inputs of a CSV file and write its outputs as CSV."""
    from ..dataset import Dataset, write_csv
    from ..predict import predict
    from ..simulate import simulate

    problems: list[str] = []
    model = _load_model(args.model, problems)
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
    raise_problems(problems, "tendonkit simulate cannot run:")
    assert model is not None and data is not None
    exp = data.experiments[0]
    y_meas = exp.y if exp.y.shape[1] else None
    if args.k is not None:
        assert y_meas is not None
        y = predict(model, exp.u, y_meas, k=args.k)
    else:
        y = simulate(model, exp.u, y=y_meas, initial=initial)  # type: ignore[arg-type]
    cols = {"t": exp.t, **{n: y[:, j] for j, n in enumerate(model.output_names)}}
    atomic_write(args.output, lambda p: write_csv(p, cols))
    what = f"{args.k}-step prediction" if args.k else f"free-run simulation (initial: {initial})"
    print(f"{what} of {len(exp.t)} samples written to {args.output}")
    return 0


def _load_model(path: str, problems: list[str]) -> Any:
    from ..errors import SchemaError
    from ..schema import Model

    try:
        return Model.load(path)
    except SchemaError as exc:
        problems.append(str(exc).replace("\n", "\n   "))
        return None


def cmd_compare(args: argparse.Namespace) -> int:
    """Fit of one or more models on data: the paper's Table I."""
    from ..compare import compare, render_compare

    problems: list[str] = []
    data_files = [f for f in args.files if f.lower().endswith(".csv")]
    model_files = [f for f in args.files if not f.lower().endswith(".csv")]
    if not data_files:
        problems.append("no data file (.csv) given.")
    if not model_files:
        problems.append("no model file (.json) given.")
    models = [_load_model(f, problems) for f in model_files]
    if args.json:
        check_output_path(args.json, args.files, problems)
    if args.plot:
        Path(args.plot).mkdir(parents=True, exist_ok=True)
    raise_problems(problems, "tendonkit compare cannot run:")
    result = compare(
        models,
        data_files,
        names=model_files,
        initial=args.initial,
        k=args.k,
        joints=args.joints,
        ee=args.ee,
        time=args.time,
        plot_dir=args.plot,
    )
    print(render_compare(result))
    if args.json:
        write_json(args.json, result)
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    """Find what the baseline model gets wrong, name the cause, extend and measure the gain."""
    from ..dataset import Dataset
    from ..manager import effects

    problems: list[str] = []
    inputs, outputs, options, _ = identifier_arguments(args, problems)
    chosen = split_names(args.effects) if args.effects else None
    if chosen:
        known = effects().names()
        problems.extend(
            f"unknown effect {e!r}; registered: {', '.join(known)}."
            for e in chosen
            if e not in known
        )
    if args.report:
        Path(args.report).mkdir(parents=True, exist_ok=True)
    for out in (args.json, args.model):
        if out:
            check_output_path(out, [args.train, args.valid], problems)
    data = []
    for path in (args.train, args.valid):
        try:
            data.append(Dataset.from_csv(path, inputs, outputs, time=args.time))
        except DataError as exc:
            problems.extend(exc.problems or [str(exc)])
    if len(data) == 2 and abs(data[0].dt - data[1].dt) > 0.01 * data[0].dt:
        problems.append(
            f"training and validation sample times differ: {data[0].dt} s and {data[1].dt} s."
        )
    raise_problems(problems, "tendonkit diagnose cannot run:")
    from ..diagnose import diagnose

    train, valid = data
    result = diagnose(
        train,
        valid,
        method=args.method,
        options=options,
        effects=chosen,
        alpha=args.alpha,
        min_relative_gain=args.min_relative_gain,
        min_gain=args.min_gain,
        seed=args.seed,
        progress=sys.stderr.isatty(),
        fallback=not args.no_fallback,
    )
    model_path = args.model or (
        str(Path(args.report) / "extended_model.json") if args.report else None
    )
    if model_path is None and args.json:
        model_path = str(Path(args.json).with_name(Path(args.json).stem + "_model.json"))
    if model_path is not None:
        Path(model_path).parent.mkdir(parents=True, exist_ok=True)
        atomic_write(model_path, result.extended.save)
    summary = result.to_dict(model_path)
    if args.json:
        write_json(args.json, summary)
    if args.report:
        from ..diagnose.report import write_report

        index = write_report(result, valid, args.report, model_path)
        summary["report"] = str(index)
    print(render_diagnosis(summary))
    return 0


def render_diagnosis(summary: dict[str, Any]) -> str:
    """Plain-text summary of a diagnosis."""
    from ..diagnose.findings import evidence_notes

    lines = [
        f"cause: {summary['cause']}",
        f"baseline ({summary['baseline']['method']}): fit {summary['baseline']['fit']:.2f} %",
    ]
    check = summary["baseline"].get("check")
    if check and check["biased"]:
        what = (
            "diagnosed against n4sid instead"
            if check["fallback"]
            else "kept (--no-fallback); its gains may measure that bias"
        )
        lines.append(
            f"note: the {check['requested_method']} baseline's training free-run error is "
            f"{check['error_ratio']:.1f}x that of a linear n4sid model (output noise biases an "
            f"equation-error fit); {what}."
        )
    ext = summary["extended"]
    if summary["cause"] != "none":
        lines.append(
            f"extended ({ext['effect']}): fit {ext['fit']:.2f} % (gain {ext['gain']:+.2f} points)"
            + (f", model: {ext['model']}" if ext.get("model") else "")
        )
    if summary.get("margin_to_runner_up") is not None:
        lines.append(f"margin to runner-up: {summary['margin_to_runner_up']:.2f} points")
    lines.extend(f"note: {n}" for n in evidence_notes(summary))
    if summary.get("ambiguous"):
        lines.append(summary["ambiguous"]["statement"])
        lines.append("to tell them apart: " + summary["ambiguous"]["experiment"])
    lines.append("findings (validation gain, p-value adjusted for trying every effect):")
    for f in summary["findings"]:
        mark = "*" if f["significant"] else " "
        p = f.get("p_adjusted", f["p_value"])
        lines.append(f" {mark} {f['cause']:<20} {f['gain']:+8.2f}  p_adj={p:.3g}")
    if summary.get("report"):
        lines.append(f"report: {summary['report']}")
    return "\n".join(lines)


def cmd_plugins(args: argparse.Namespace) -> int:
    """List registered identifiers and effects."""
    from ..manager import FAILURES, effects, identifiers, plugin_manager

    plugin_manager()
    ids = identifiers()
    effs = effects()
    data = {
        "identifiers": [
            {"name": e.name, "description": e.description, "plugin": e.plugin, "options": e.options}
            for e in ids
        ],
        "effects": [
            {"name": e.name, "cause": e.cause, "description": getattr(e, "description", "")}
            for e in effs
        ],
        "failed": [{"plugin": n, "reason": r} for n, r in FAILURES],
    }
    if args.json:
        write_json(args.json, data)
    width = max([len(e.name) for e in ids] + [len(e.name) for e in effs] + [8])
    print("identifiers:")
    for e in ids:
        print(f"  {e.name.ljust(width)}  {e.description}")
    if len(effs):
        print("effects (diagnose):")
        for e in effs:
            print(f"  {e.name.ljust(width)}  [{e.cause}] {getattr(e, 'description', '')}")
    for name, reason in FAILURES:
        print(f"not loaded: {name}: {reason}", file=sys.stderr)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the main job and write its report."""
    from ..robot.study import run_demo

    out = Path(args.out)
    problems: list[str] = []
    if out.exists() and not out.is_dir():
        problems.append(f"--out {str(out)!r} exists and is not a folder.")
    raise_problems(problems, "tendonkit demo cannot run:")
    run_demo(out, quick=args.quick, seed=args.seed)
    return 0


# -- parser ---------------------------------------------------------------------------------------

_EXTRA_COMMANDS: list[tuple[str, str]] = [
    # (module, function) pairs contributing subcommands that live in their own modules.
    ("tendonkit.cli.robot", "add_commands"),
    ("tendonkit.cli.mpc", "add_commands"),
]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``tendonkit`` command."""
    from .. import __version__

    parser = _Parser(
        prog="tendonkit",
        description="Identify, diagnose, export and control dynamic models of a "
        "tendon-actuated continuum robot.",
    )
    parser.add_argument("--version", action="version", version=f"tendonkit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("identify", help="identify a model from CSV data")
    p.add_argument("data", nargs="+", help="CSV file(s); several files are several experiments")
    p.add_argument("--method", default="arx", help="identifier name (see 'tendonkit plugins')")
    p.add_argument("--inputs", required=True, help="input columns, comma separated")
    p.add_argument("--outputs", required=True, help="output columns, comma separated")
    p.add_argument("--option", action="append", metavar="KEY=VALUE", help="identifier option")
    p.add_argument("-o", "--output", required=True, help="model JSON file to write")
    p.add_argument("--time", default="t", help="time column in seconds (default: t)")
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
    p.add_argument("--joints", action="store_true", help="also reconstruct q3..q6 and score them")
    p.add_argument("--ee", action="store_true", help="also score the end-effector error (cm)")
    p.add_argument("--plot", help="write figures (PNG) into this folder")
    p.add_argument("--time", default="t", help="time column (default: t)")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("diagnose", help="name what a model gets wrong, extend it, measure the gain")
    p.add_argument("train", help="training CSV")
    p.add_argument("valid", help="validation CSV (never used to fit or choose anything)")
    p.add_argument("--inputs", required=True, help="input columns, comma separated")
    p.add_argument("--outputs", required=True, help="output columns, comma separated")
    p.add_argument("--method", default="arx", help="baseline identifier (default: arx)")
    p.add_argument("--option", action="append", metavar="KEY=VALUE", help="baseline option")
    p.add_argument("--effects", help="effects to try, comma separated (default: all registered)")
    p.add_argument("--alpha", type=float, default=0.01, help="significance level (default 0.01)")
    p.add_argument(
        "--min-relative-gain",
        type=float,
        default=0.02,
        help="smallest relative drop of the validation error energy that counts (default 0.02)",
    )
    p.add_argument(
        "--min-gain",
        type=float,
        default=0.25,
        help="smallest validation gain, in points of fit, that can name a cause (default 0.25)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed for every random choice")
    p.add_argument(
        "--no-fallback",
        action="store_true",
        help="keep the requested baseline even when a linear n4sid model simulates the training "
        "data far better (by default diagnose then uses n4sid; see docs/diagnose.md)",
    )
    p.add_argument("--json", help="write the result as JSON here")
    p.add_argument(
        "--model", help="write the extended model here (default: next to --json/--report)"
    )
    p.add_argument("--report", help="write an HTML report with figures into this folder")
    p.add_argument("--time", default="t", help="time column (default: t)")
    p.set_defaults(func=cmd_diagnose)

    p = sub.add_parser("plugins", help="list registered identifiers and effects")
    p.add_argument("--json", help="write the list as JSON here")
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("demo", help="run the main job end to end and write a report")
    p.add_argument("--out", default="demo-report", help="output folder (default: demo-report)")
    p.add_argument("--quick", action="store_true", help="smaller data, finishes in about a minute")
    p.add_argument("--seed", type=int, default=0, help="seed of every random choice (default 0)")
    p.set_defaults(func=cmd_demo)

    import importlib

    for module, func in _EXTRA_COMMANDS:
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        getattr(mod, func)(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args.func(args) or 0)
    except TendonkitError as exc:
        print(f"tendonkit: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("tendonkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
