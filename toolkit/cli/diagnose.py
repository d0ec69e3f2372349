"""The ``diagnose`` subcommand: name what a model gets wrong, extend it, measure the gain."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ..dataset import Dataset
from ..diagnose import diagnose
from ..diagnose.findings import (
    between_text,
    evidence_notes,
    experiment_lead,
    reshaping_notes,
    runner_up_text,
)
from ..diagnose.report import write_report
from ..errors import DataError, TendonkitWarning
from ..manager import effects
from ..manager import identifiers as identifier_registry
from .common import (
    atomic_write,
    check_output_dir,
    check_output_path,
    identifier_arguments,
    output_dirs,
    raise_problems,
    same_file,
    seed_argument,
    split_names,
    warn,
    write_json,
)


def add_commands(sub: Any) -> None:
    """Add ``diagnose`` to the ``tendonkit`` subparsers."""
    p = sub.add_parser("diagnose", help="name what a model gets wrong, extend it, measure the gain")
    p.add_argument("train", help="training CSV")
    p.add_argument("valid", help="validation CSV (never used to fit or choose anything)")
    p.add_argument("--inputs", required=True, help="input columns, comma separated")
    p.add_argument("--outputs", required=True, help="output columns, comma separated")
    p.add_argument(
        "--method",
        default="auto",
        help="baseline identifier; 'auto' (default): an ARX whose dead times, orders and offset "
        "are chosen on the training data (--option then overrides the ARX options)",
    )
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
    p.add_argument(
        "--max-causes",
        type=int,
        default=3,
        help="most causes named in sequence, each step extending the model of the step before "
        "(default 3; 1 stops at the first cause)",
    )
    p.add_argument(
        "--no-refine",
        action="store_true",
        help="keep the named extensions as fitted by least squares (by default each is refined "
        "by its simulation error before it is reported and extended further)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="worker processes trying the effects (default 1; worth it on long records only, "
        "docs/campaigns.md)",
    )
    p.add_argument(
        "--versus",
        metavar="METHOD",
        help="also identify METHOD with its default options on the training data and measure "
        "the final model against it (e.g. pem, the best linear model; costs its identification)",
    )
    p.add_argument("--seed", type=seed_argument, default=0, help="seed for every random choice")
    p.add_argument(
        "--no-fallback",
        action="store_true",
        help="keep the requested baseline even when a linear n4sid (or, for a baseline that "
        "fits its own training data below 50 %%, pem) model simulates the training data far "
        "better (by default diagnose then uses that model; see docs/diagnose.md)",
    )
    p.add_argument("--json", help="write the result as JSON here")
    p.add_argument(
        "--model", help="write the extended model here (default: next to --json/--report)"
    )
    p.add_argument("--report", help="write an HTML report with figures into this folder")
    p.add_argument("--time", default="t", help="time column (default: t)")
    p.set_defaults(func=cmd_diagnose)


def _same_records(a: Dataset, b: Dataset) -> bool:
    """Whether two datasets hold the same samples (one file given twice, or a copy of it)."""
    return len(a.experiments) == len(b.experiments) and all(
        np.array_equal(x.u, y.u) and np.array_equal(x.y, y.y)
        for x, y in zip(a.experiments, b.experiments, strict=True)
    )


def cmd_diagnose(args: argparse.Namespace) -> int:
    """Find what the baseline model gets wrong, name the cause, extend and measure the gain."""
    problems: list[str] = []
    auto = args.method == "auto"
    if auto:  # the automatic baseline is an ARX: its options are checked as such
        args.method = "arx"
    inputs, outputs, options, _ = identifier_arguments(args, problems)
    method = "auto" if auto else args.method
    chosen = split_names(args.effects) if args.effects is not None else None
    if args.versus is not None and args.versus not in identifier_registry().names():
        problems.append(
            f"--versus: unknown identifier {args.versus!r}; registered: "
            f"{', '.join(identifier_registry().names())}."
        )
    if args.effects is not None and not chosen:
        problems.append(f"--effects {args.effects!r} names no effect.")
    if chosen:
        known = effects().names()
        problems.extend(
            f"unknown effect {e!r}; registered: {', '.join(known)}."
            for e in chosen
            if e not in known
        )
    files = [args.train, args.valid]
    if args.report:
        check_output_dir(args.report, files, problems, what="--report")
    for option, out in (("--json", args.json), ("--model", args.model)):
        if out:
            check_output_path(out, files, problems, what=option, creates=[args.report])
    if args.json and args.model and same_file(args.json, args.model):
        problems.append("--json and --model name the same file.")
    for option, out in (("--json", args.json), ("--model", args.model)):
        if out and args.report and same_file(out, args.report):
            problems.append(f"{option} and --report name the same path.")
    data = []
    for path in (args.train, args.valid):
        try:
            data.append(Dataset.from_csv(path, inputs, outputs, time=args.time))
        except DataError as exc:
            problems.extend(exc.problems or [str(exc)])
    if len(data) == 2 and _same_records(*data):
        problems.append(
            f"the validation data {args.valid!r} are the training data {args.train!r}: the test "
            "needs a record the models were not fitted on (collect a second one, or split one)."
        )
    if len(data) == 2 and abs(data[0].dt - data[1].dt) > 0.01 * data[0].dt:
        problems.append(
            f"training and validation sample times differ: {data[0].dt} s and {data[1].dt} s."
        )
    raise_problems(problems, "tendonkit diagnose cannot run:")
    told: list[str] = []
    with output_dirs(args.report), warnings.catch_warnings():
        warnings.simplefilter("always", TendonkitWarning)
        warnings.showwarning = _teller(told, warnings.showwarning)
        train, valid = data
        result = diagnose(
            train,
            valid,
            method=method,
            options=options,
            effects=chosen,
            alpha=args.alpha,
            min_relative_gain=args.min_relative_gain,
            min_gain=args.min_gain,
            seed=args.seed,
            progress=sys.stderr.isatty(),
            fallback=not args.no_fallback,
            max_causes=args.max_causes,
            refine=not args.no_refine,
            jobs=args.jobs,
            versus=args.versus,
        )
        model_path = args.model or (
            str(Path(args.report) / "extended_model.json") if args.report else None
        )
        if model_path is None and args.json:
            model_path = str(Path(args.json).with_name(Path(args.json).stem + "_model.json"))
        if model_path is not None:
            atomic_write(model_path, result.extended.save)
        summary = result.to_dict(model_path)
        summary["warnings"] = list(told)
        if args.json:
            write_json(args.json, summary)
        if args.report:
            index = write_report(result, valid, args.report, model_path)
            summary["report"] = str(index)
    print(render_diagnosis(summary))
    return 0


def _teller(told: list[str], shown: Any) -> Any:
    """A ``warnings.showwarning`` that prints a :class:`TendonkitWarning` as the CLI's
    ``tendonkit: warning:`` line when it is raised (kept in ``told`` for ``--json``) and
    shows any other warning as ``shown`` does."""

    def show(message: Any, category: Any, filename: str, lineno: int, *rest: Any) -> None:
        if issubclass(category, TendonkitWarning):
            told.append(str(message))
            warn(str(message))
        else:
            shown(message, category, filename, lineno, *rest)

    return show


def _render_step(st: dict[str, Any]) -> list[str]:
    """The lines of one step of the sequence of causes."""
    notes = [f"     {n}" for n in reshaping_notes(st)]
    if st["cause"] == "none":
        top = st["findings"][0] if st["findings"] else None
        best = (
            f"{top['cause']} {top['gain']:+.2f} points"
            if top and top.get("gain") is not None
            else "none"
        )
        what = "confirmed" if st.get("stop") else "significant"
        lines = [
            f"  {st['step']}. nothing more {what} from {st['fit_before']:.2f} % (best of "
            f"{len(st['findings'])} effects tried: {best})"
        ]
        if st.get("stop"):
            notes.append(f"     {st['stop']}")
        return lines + notes
    tested = st.get("tested_fit", st["fit"])
    refined = f", refined {st['fit']:.2f} %" if abs(st["fit"] - tested) >= 0.005 else ""
    lines = [
        f"  {st['step']}. {st['cause']} ({st['effect']}{between_text(st.get('params'))}): fit "
        f"{st['fit_before']:.2f} -> {tested:.2f} % (gain {st['gain']:+.2f} points, "
        f"p_adj={st['p_adjusted']:.3g}){refined}"
    ]
    if st.get("ambiguous"):
        lines.append(f"     tie: {st['ambiguous']['statement']}")
    lines += notes
    if st.get("stop"):
        lines.append(f"     stopped: {st['stop']}")
    return lines


def render_diagnosis(summary: dict[str, Any]) -> str:
    """Plain-text summary of a diagnosis."""
    lines = [
        f"cause: {summary['cause']}",
        f"baseline ({summary['baseline']['method']}): fit {summary['baseline']['fit']:.2f} %",
    ]
    choice = summary["baseline"].get("choice")
    check = summary["baseline"].get("check")
    if choice:
        replaced = summary["baseline"]["method"] != "arx"
        lines.append(
            f"note: {choice['statement']}"
            + (" — not the baseline diagnosed: see the fallback below" if replaced else "")
        )
    if check and check["biased"]:
        behind = check.get("reference_behind_dead_times") or {}
        dead_times = bool(behind.get("decides"))
        order = behind.get("order")
        instead = (
            "n4sid instead"
            if not dead_times
            else f"n4sid of order {order} without the dead times instead (left to the diagnosis)"
            if order
            else "n4sid's automatic order instead (n4sid of its order behind the dead times "
            "could not be identified without them)"
        )
        what = (
            f"diagnosed against {instead}"
            if check["fallback"]
            else "kept (--no-fallback); its gains may measure that bias"
        )
        if check["fallback"] and "refined_fit" in check:
            what += (
                f", refined by its simulation error (training fit {check['reference_fit']:.1f} "
                f"-> {check['refined_fit']:.1f} %), each effect's extension refined the same way"
            )
        if check["fallback"] and check.get("pem", {}).get("fallback"):
            what += "; then replaced by pem's model (next note)"
        if dead_times:
            dead = ", ".join(f"{n} {d:g}" for n, d in behind["dead_times"].items())
            against = (
                f"{behind['error_ratio']:.1f}x that of a linear n4sid model behind the dead "
                f"times found ({dead} samples) and {check['error_ratio']:.1f}x that of one "
                "without them, whose automatic order cannot hold them"
            )
        else:
            against = (
                f"{check['error_ratio']:.1f}x that of a linear n4sid model (output noise "
                "biases an equation-error fit)"
            )
        lines.append(
            f"note: the {check['requested_method']} baseline's training free-run error is "
            f"{against}; {what}."
        )
    pem = check.get("pem") if check else None
    if pem and pem["fallback"]:
        lines.append(
            f"note: the baseline's free run fits its own training data {pem['baseline_fit']:.1f} %;"
            f" pem's linear model (order {pem['order']}, chosen on held-out data) fits "
            f"{pem['reference_fit']:.1f} % and is the baseline instead, each effect's extension "
            "built by n4sid of that order and refined by its simulation error."
        )
    if summary["baseline"].get("unfit"):
        lines.append(f"note: unfit for diagnosis: {summary['baseline']['unfit']}")
    ext = summary["extended"]
    if summary["cause"] != "none":
        effects = ext.get("effects") or [ext["effect"]]
        named = (
            f"{ext['effect']}{between_text(ext.get('params'))}"
            if len(effects) == 1
            else ", ".join(effects)
        )
        total = ext.get("total_gain", ext["gain"])
        # the fit is the final (refined) model's; the gain the test measured is the first
        # step's extension as least squares fits it, which may differ
        tested = (
            f"; as tested {ext['gain']:+.2f}"
            if len(effects) == 1 and abs(total - ext["gain"]) >= 0.005
            else ""
        )
        lines.append(
            f"extended ({named}): fit {ext['fit']:.2f} % ({total:+.2f} points over the "
            f"baseline{tested})" + (f", model: {ext['model']}" if ext.get("model") else "")
        )
    sequence = summary.get("sequence") or []
    if len(sequence) > 1 or (sequence and sequence[0].get("stop")):
        lines.append(
            "sequence of causes (each step extends the structure of the step before, refitted "
            "by least squares as its candidates are; the gain is the extension's as tested, "
            "'refined' its fit refined by simulation error):"
        )
        for st in sequence:
            lines.extend(_render_step(st))
        lines.append(
            f"final model: fit {ext['fit']:.2f} % (total gain {ext['total_gain']:+.2f} points), "
            f"causes: {', '.join(summary['causes'])}"
        )
    before, after = summary["baseline"].get("rmse_per_output"), ext.get("rmse_per_output")
    if before and after and summary["cause"] != "none":
        lines.append(
            "validation RMSE (output units): "
            + ", ".join(f"{n} {before[n]:.4g} -> {after[n]:.4g}" for n in after if n in before)
        )
    versus = summary.get("versus")
    if versus and "fit" in versus:
        rmse = versus.get("rmse_per_output") or {}
        lines.append(
            f"against {versus['method']} (default options, same data): fit {versus['fit']:.2f} % "
            f"-> final model {ext['fit']:.2f} % (gain {versus['extended_gain']:+.2f} points)"
            + (f"; its RMSE {', '.join(f'{n} {v:.4g}' for n, v in rmse.items())}" if rmse else "")
        )
    elif versus:
        lines.append(f"against {versus['method']}: not identified ({versus.get('error')})")
    if summary.get("margin_to_runner_up") is not None:
        lines.append(
            f"margin to runner-up{runner_up_text(summary)}: "
            f"{summary['margin_to_runner_up']:.2f} points"
        )
    lines.extend(f"note: {n}" for n in evidence_notes(summary))
    if summary.get("ambiguous"):
        lines.append(summary["ambiguous"]["statement"])
        lines.append(
            f"{experiment_lead(summary['ambiguous'])}: {summary['ambiguous']['experiment']}"
        )
    lines.append("findings (validation gain, p-value adjusted for trying every effect):")
    for f in summary["findings"]:
        mark = "*" if f["significant"] else " "
        p = f.get("p_adjusted", f["p_value"])
        gain = "diverged" if f.get("diverged") else f"{f['gain']:+8.2f}"
        lines.append(f" {mark} {f['cause']:<20} {gain:>8}  p_adj={p:.3g}")
    if summary.get("report"):
        lines.append(f"report: {summary['report']}")
    return "\n".join(lines)
