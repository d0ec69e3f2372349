"""The ``export`` subcommand: a model JSON as an FMI 2.0 or 3.0 co-simulation FMU.

The FMU side (:mod:`tendonkit.fmu`, pythonfmu) is imported inside the command, so
``tendonkit --help`` stays instant.
"""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import DataError
from ..robot.reconstruct import Ratios
from .common import check_output_path, load_model, raise_problems


def add_commands(sub: Any) -> None:
    """Add ``export`` to the ``tendonkit`` subparsers."""
    p = sub.add_parser(
        "export",
        help="export a model as an FMI co-simulation FMU (compiled C; no Python needed to run it)",
    )
    p.add_argument("model", help="model JSON file")
    p.add_argument("-o", "--output", required=True, help="FMU file to write")
    p.add_argument(
        "--ratios",
        help="JSON file with the joint ratios {q3, q4, q5, q6} (q3/q1, q4/q2, q5/q1, q6/q2; "
        "the format compare --joints reports estimates in; default: the paper's)",
    )
    p.add_argument(
        "--no-kinematics",
        action="store_true",
        help="export only the modelled outputs (no q3..q6, no end effector)",
    )
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default: 2)")
    p.add_argument(
        "--backend",
        choices=("c", "python"),
        help="c: the compiled runtime, runs in any FMI importer without Python (default; "
        "falls back to python, with a note, for a model part that has no C form); "
        "python: a pythonfmu slave that needs tendonkit in the importer's Python",
    )
    p.add_argument(
        "--platform",
        action="append",
        choices=("linux64", "win64", "darwin64"),
        help="put binaries in for this platform (repeatable; default: every platform that "
        "can be built here)",
    )
    p.set_defaults(func=cmd_export)


def _read_ratios(path: str, problems: list[str]) -> tuple[float, ...] | None:
    """The four ratios (r3, r4, r5, r6) of a ratios file in the format of
    :class:`tendonkit.robot.reconstruct.Ratios` (keys q3, q4, q5, q6 — what ``compare --joints``
    reports as estimates)."""
    try:
        r = Ratios.load(path)
    except DataError as exc:
        problems.extend(f"--ratios: {p}" for p in (exc.problems or [str(exc)]))
        return None
    bad = [f"{k}={v!r}" for k, v in r.to_dict().items() if not 0 < v <= 1]
    if bad:
        problems.append(f"--ratios: ratios must be in (0, 1], found {', '.join(bad)}.")
        return None
    return (r.r3, r.r4, r.r5, r.r6)


def cmd_export(args: argparse.Namespace) -> int:
    """Export a model JSON as an FMI co-simulation FMU."""
    # lazy: keeps the CLI off tendonkit.fmu (pythonfmu) until a command needs it
    from tendonkit.fmu.build import export_model_fmu, model_fmu_problems

    problems: list[str] = []
    model = load_model(args.model, problems)
    check_output_path(args.output, [args.model], problems)
    if not str(args.output).lower().endswith(".fmu"):
        problems.append(f"output {args.output!r} must end in .fmu.")
    ratios = _read_ratios(args.ratios, problems) if args.ratios else None
    if args.ratios and args.no_kinematics:
        problems.append("--ratios has no effect with --no-kinematics.")
    if args.backend == "python" and args.fmi == 3:
        problems.append("--backend python writes FMI 2.0 only (pythonfmu); use --backend c.")
    if model is not None:
        problems.extend(model_fmu_problems(model, kinematics=not args.no_kinematics))
    raise_problems(problems, "tendonkit export cannot run:")
    assert model is not None
    result = export_model_fmu(
        model,
        args.output,
        ratios=ratios,
        kinematics=not args.no_kinematics,
        backend=args.backend,
        fmi=args.fmi,
        platforms=args.platform,
    )
    what = "modelled outputs only" if args.no_kinematics else "q1..q6 and the end effector"
    print(
        f"{model.kind} model {model.name!r} exported to {result.path} "
        f"({result.summary()}; step {model.dt:g} s, {what})"
    )
    for note in result.notes:
        print(f"note: {note}")
    return 0
