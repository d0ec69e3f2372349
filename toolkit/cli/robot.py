"""Robot-side subcommands of ``tendonkit``: ``plant build``, ``collect`` and ``demo``.

:func:`add_commands` is called by :func:`tendonkit.cli.app.build_parser`.  The FMU side
(:mod:`tendonkit.fmu`), fmpy, pythonfmu and matplotlib are imported inside the commands, so
``tendonkit --help`` stays instant.  Every user error is collected and reported at once (exit
status 2).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import OptionError, SchemaError
from ..robot.collect import collect, fmu_parameters
from ..robot.figures import fig2
from ..robot.protocol import circles, petal, pseudo_random
from ..robot.study import run_demo
from .common import (
    atomic_write,
    check_input_file,
    check_output_dir,
    check_output_path,
    output_dirs,
    positive_float,
    raise_problems,
    seed_argument,
    write_json,
)

PROTOCOLS = ("circles", "random", "petal")


def add_commands(sub: Any) -> None:
    """Add ``plant build``, ``collect`` and ``demo`` to the ``tendonkit`` subparsers."""
    plant = sub.add_parser("plant", help="the plant FMU (physics simulator of the robot)")
    plant_sub = plant.add_subparsers(
        dest="plant_command", metavar="COMMAND", parser_class=type(plant)
    )
    plant.set_defaults(func=lambda args: _usage(plant))
    p = plant_sub.add_parser("build", help="build the plant FMU with chosen hidden effects")
    p.add_argument("-o", "--output", default="plant.fmu", help="FMU file (default: plant.fmu)")
    _effect_arguments(p)
    p.add_argument(
        "--preset",
        default="nominal",
        help="base configuration: nominal (default) or paper_like",
    )
    p.set_defaults(func=cmd_plant_build)

    p = sub.add_parser("collect", help="collect data from the plant FMU with the paper's protocol")
    p.add_argument("--protocol", required=True, choices=PROTOCOLS, help="what to play")
    p.add_argument("--plant", help="plant FMU (default: the nominal plant, built and cached)")
    _effect_arguments(p)
    p.add_argument("--preset", help="base configuration of the default plant (not with --plant)")
    p.add_argument(
        "--seed", type=seed_argument, help="seed of the random protocol and of the sensor noise"
    )
    p.add_argument(
        "--duration",
        type=positive_float,
        help="seconds: length of the random protocol (default 240); circles/petal are cut there",
    )
    p.add_argument(
        "--radii",
        nargs="+",
        help="circle radii in cm, e.g. '2 6 12' or '2,6,12' (default 1..12)",
    )
    p.add_argument(
        "--laps", type=positive_float, help="laps per circle / petal traversals (default 2 / 1)"
    )
    p.add_argument("-o", "--output", required=True, help="CSV file to write")
    p.add_argument("--plot", help="write the paper's Fig. 2 equivalent (PNG) into this folder")
    p.add_argument("--json", help="also write a JSON summary here")
    p.add_argument(
        "--no-progress", action="store_true", help="no progress bar (default: on a terminal)"
    )
    p.set_defaults(func=cmd_collect)

    p = sub.add_parser("demo", help="run the main job end to end and write a report")
    p.add_argument("--out", default="demo-report", help="output folder (default: demo-report)")
    p.add_argument("--quick", action="store_true", help="smaller data, finishes in about a minute")
    p.add_argument(
        "--seed", type=seed_argument, default=0, help="seed of every random choice (default 0)"
    )
    p.set_defaults(func=cmd_demo)


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _effect_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--effect",
        action="extend",
        nargs="+",
        metavar="NAME[=VALUE]",
        help="hidden effect: a switch letter A B D Z F G K N L (e.g. 'A', 'D=0.12', "
        "'G=horiz_tilt') or a plant parameter (e.g. 'friction_on=1', 'delay_s=0.09')",
    )


# ------------------------------------------------------------------------------- plant build
def cmd_plant_build(args: argparse.Namespace) -> int:
    """Build the plant FMU with the requested effects as parameter start values."""
    # lazy: keeps the CLI off tendonkit.fmu (pythonfmu) until a command needs it
    # lazy: keeps this module off tendonkit.fmu until needed
    from tendonkit.fmu.build import build_plant_fmu, plant_parameters
    from tendonkit.fmu.plant import config_from_dict

    problems: list[str] = []
    check_output_path(args.output, [], problems)
    if not str(args.output).lower().endswith(".fmu"):
        problems.append(f"output {args.output!r} must end in .fmu.")
    params = None
    try:
        params = plant_parameters(args.effect or [], args.preset)
    except OptionError as exc:
        problems.extend(exc.problems or [str(exc)])
    raise_problems(problems, "tendonkit plant build cannot run:")
    assert params is not None
    config, robot = config_from_dict(params)
    build_plant_fmu(args.output, config, robot)
    effects = ", ".join(config.effects) or "none (nominal)"
    print(f"plant FMU written to {args.output} (effects: {effects}; step 30 ms)")
    return 0


# ------------------------------------------------------------------------------- collect
def _radii(items: list[str] | None, problems: list[str]) -> list[float] | None:
    if not items:
        return None
    out: list[float] = []
    for item in items:
        for part in item.split(","):
            if not part.strip():
                continue
            try:
                cm = float(part)
            except ValueError:
                problems.append(f"--radii: {part!r} is not a number (cm).")
                continue
            # checked here in the unit the user wrote (the protocol checks metres)
            if not 0.01 <= cm <= 15.0:
                problems.append(f"--radii: {part.strip()} cm is outside 0.01 to 15 cm.")
                continue
            out.append(cm / 100.0)
    if not any(part.strip() for item in items for part in item.split(",")):
        problems.append("--radii names no radius.")  # (a radius refused above says why)
    return out


def _protocol(args: argparse.Namespace, problems: list[str]) -> Any:
    radii = _radii(args.radii, problems)
    if args.radii and args.protocol != "circles":
        problems.append("--radii applies only to --protocol circles.")
    if args.seed is not None and args.seed < 0:
        problems.append(f"--seed must be >= 0, found {args.seed}.")
    if problems:
        return None
    try:
        if args.protocol == "circles":
            laps = 2.0 if args.laps is None else args.laps
            prot = circles(radii=radii, laps=laps)
        elif args.protocol == "petal":
            prot = petal(laps=1.0 if args.laps is None else args.laps)
        else:
            if args.laps is not None:
                problems.append("--laps does not apply to --protocol random.")
                return None
            duration = 240.0 if args.duration is None else args.duration
            return pseudo_random(duration, seed=args.seed or 0)
    except OptionError as exc:
        problems.extend(exc.problems or [str(exc)])
        return None
    if args.duration is not None:
        prot = _truncate(prot, args.duration)
    return prot


def _truncate(prot: Any, seconds: float) -> Any:
    """The first ``seconds`` of a protocol."""
    n = max(1, min(prot.n_samples, round(seconds / prot.h)))
    arrays = ("t", "ee_ref", "q_ref", "u", "pretension", "segment", "phase")
    return replace(prot, **{name: getattr(prot, name)[:n] for name in arrays})


def cmd_collect(args: argparse.Namespace) -> int:
    """Drive the plant FMU with a protocol and write the frames as CSV."""
    # lazy: keeps the CLI off tendonkit.fmu (pythonfmu) until a command needs it
    from tendonkit.fmu.build import cached_plant_fmu, plant_parameters

    problems: list[str] = []
    inputs = [args.plant] if args.plant else []
    check_output_path(args.output, inputs, problems, what="-o/--output")
    if args.json:
        check_output_path(args.json, [*inputs, args.output], problems, what="--json")
    if args.plot:
        check_output_dir(args.plot, [*inputs, args.output], problems, what="--plot")
    if args.plant and args.preset:
        problems.append("--preset applies to the default plant only; with --plant use --effect.")
    plant_ok = not args.plant or check_input_file(args.plant, problems, what="plant FMU")
    prot = _protocol(args, problems)
    overrides: dict[str, Any] = {}
    params: dict[str, Any] | None = None
    if plant_ok:
        try:
            if args.plant:
                base = fmu_parameters(args.plant)
                full = plant_parameters(args.effect or [], base=base)
                overrides = {k: v for k, v in full.items() if k in base and base[k] != v}
            else:
                params = plant_parameters(args.effect or [], args.preset or "nominal")
        except (OptionError, SchemaError) as exc:
            problems.extend(exc.problems or [str(exc)])
    raise_problems(problems, "tendonkit collect cannot run:")
    plant = Path(args.plant) if args.plant else cached_plant_fmu(params)
    rec = collect(
        prot,
        plant=plant,
        effects=overrides,
        seed=args.seed,
        progress=False if args.no_progress else None,
    )
    atomic_write(args.output, rec.to_csv)
    figures: list[str] = []
    if args.plot:
        with output_dirs(args.plot):
            figures = [str(p) for p in fig2(rec.columns, args.plot, prot.ee_ref, title=prot.name)]
    summary = {
        "output": str(args.output),
        "plant": str(plant),
        "protocol": prot.name,
        "samples": rec.n_samples,
        "duration_s": rec.n_samples * prot.h,
        "parameters": rec.parameters,
        "figures": figures,
    }
    if args.json:
        write_json(args.json, summary)
    effects = [k[:-3] for k, v in rec.parameters.items() if k.endswith("_on") and v]
    if rec.parameters.get("mount", "none") != "none":
        effects.append(f"mount {rec.parameters['mount']}")
    print(
        f"collected {rec.n_samples} frames ({rec.n_samples * prot.h:.1f} s of {prot.name}) "
        f"from {plant.name} (effects: {', '.join(effects) or 'none'}) into {args.output}"
        + (f"; figures in {args.plot}" if figures else "")
    )
    return 0


# ------------------------------------------------------------------------------- demo
def cmd_demo(args: argparse.Namespace) -> int:
    """Run the main job and write its report."""
    out = Path(args.out)
    problems: list[str] = []
    if out.exists() and not out.is_dir():
        problems.append(f"--out {str(out)!r} exists and is not a folder.")
    raise_problems(problems, "tendonkit demo cannot run:")
    run_demo(out, quick=args.quick, seed=args.seed)
    return 0
