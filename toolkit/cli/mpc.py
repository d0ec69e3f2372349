"""The ``tendonkit mpc`` subcommand: track a reference on the plant FMU with an MPC.

:func:`add_commands` is called by :func:`tendonkit.cli.app.build_parser`.  The model decides the
controller (linear MPC for ``state_space``/``arx`` models, nonlinear MPC for ``sparse_map``
models, :func:`tendonkit.robot.cosim.make_controller`); the plant is an FMU given with ``--plant``
or the nominal one, built once and cached.  fmpy, cvxpy and matplotlib are imported inside the
command, so ``tendonkit --help`` stays instant.  Every user error is reported at once (exit
status 2).

Examples
--------
Track the default petal on the nominal plant and compare with the open-loop controller::

    tendonkit mpc model.json --reference petal --open-loop --json out.json --plot figs
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OptionError, SchemaError
from ..robot.collect import fmu_parameters
from ..robot.cosim import (
    DEFAULTS,
    REFERENCES,
    STEP,
    ControllerSettings,
    controller_kind,
    make_controller,
    make_reference,
    open_loop,
    plot_tracking,
    run,
)
from ..simulate import DT_TOLERANCE
from .common import (
    check_output_dir,
    check_output_path,
    load_model,
    positive_float,
    raise_problems,
    same_file,
    seed_argument,
    warn,
    write_json,
)

__all__ = ["add_commands", "cmd_mpc"]


def add_commands(sub: Any) -> None:
    """Add the ``mpc`` subcommand to the ``tendonkit`` subparsers."""

    p = sub.add_parser(
        "mpc",
        help="track a reference on the plant FMU with MPC (co-simulation, the paper's Fig. 5)",
        description="Co-simulate the plant FMU with a linear (state_space/arx model) or "
        "nonlinear (sparse_map model) MPC tracking a reference; report the tracking errors, "
        "solve times, fallbacks and input-bound violations.",
    )
    p.add_argument("model", help="model JSON file: inputs = the four tendon forces, outputs q1, q2")
    p.add_argument("--plant", help="plant FMU (default: the nominal plant, built and cached)")
    p.add_argument(
        "--effect",
        action="extend",
        nargs="+",
        metavar="NAME[=VALUE]",
        help="hidden effect of the plant: a switch letter A B D Z F G K N L (e.g. 'A', "
        "'D=0.12', 'G=horiz_tilt') or a plant parameter (e.g. 'friction_on=1', 'delay_s=0.09')",
    )
    p.add_argument("--preset", help="base configuration of the default plant: nominal, paper_like")
    p.add_argument("--seed", type=seed_argument, help="seed of the plant's sensor noise")
    p.add_argument("--reference", required=True, choices=REFERENCES, help="what to track")
    p.add_argument(
        "--duration", type=positive_float, help="seconds (default: one petal lap, 2 circle laps)"
    )
    p.add_argument(
        "--speed", type=float, default=2.5, help="end-effector speed, cm/s (default 2.5)"
    )
    p.add_argument(
        "--amplitude", type=float, default=9.0, help="petal amplitude / circle radius, cm (9)"
    )
    p.add_argument("--petals", type=int, default=3, help="the petal's rose parameter k (3)")
    p.add_argument("--horizon", type=int, help="prediction horizon, samples of 30 ms (20)")
    p.add_argument("--Q", type=float, help="weight of the joint error, 1/rad² (1e4)")
    p.add_argument("--R", type=float, help="weight of the input moves, 1/N² (0.3)")
    p.add_argument("--solver", default="clarabel", choices=["clarabel", "osqp"], help="QP solver")
    p.add_argument(
        "--design-path",
        action="store_true",
        help="solve through cvxpy's problem.solve instead of the direct solver interface",
    )
    p.add_argument(
        "--open-loop",
        action="store_true",
        help="also run the open-loop kinematic controller on the same plant and reference",
    )
    p.add_argument("--json", help="write the results as JSON here")
    p.add_argument("--plot", help="write the paper's Fig. 5 equivalent (PNG) into this folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_mpc)


def _plant(args: argparse.Namespace, problems: list[str]) -> tuple[Any, dict[str, Any], Any]:
    """(FMU path or None, parameter overrides, full parameters for the cached plant)."""
    # lazy: keeps this module off tendonkit.fmu until needed
    from tendonkit.fmu.build import plant_parameters

    effects = list(args.effect or [])
    if args.seed is not None:
        if args.seed < 0:
            problems.append(f"--seed must be >= 0, found {args.seed}.")
        else:
            effects.append(f"seed={args.seed}")
    if args.plant:
        if args.preset:
            problems.append(
                "--preset applies to the default plant only; with --plant use --effect."
            )
        if not Path(args.plant).is_file():
            problems.append(f"plant FMU {args.plant!r} does not exist.")
            try:  # still check the effect names against the nominal plant's parameters
                plant_parameters(effects)
            except OptionError as exc:
                problems.extend(exc.problems or [str(exc)])
            return None, {}, None

        try:
            base = fmu_parameters(args.plant)
            full = plant_parameters(effects, base=base)
        except (OptionError, SchemaError) as exc:
            problems.extend(exc.problems or [str(exc)])
            return None, {}, None
        except Exception as exc:  # fmpy raises bare exceptions for broken archives
            problems.append(f"plant FMU {args.plant!r} is not readable: {exc}")
            return None, {}, None
        overrides = {k: v for k, v in full.items() if k in base and base[k] != v}
        return Path(args.plant), overrides, None
    try:
        params = plant_parameters(effects, args.preset or "nominal")
    except OptionError as exc:
        problems.extend(exc.problems or [str(exc)])
        return None, {}, None
    return None, {}, params


#: Longest prediction horizon (samples): 300 samples is 9 s of preview at 30 ms, ten times the
#: robot's slowest mode, and keeps the QP (about 2,000 variables) solvable within a step.
MAX_HORIZON = 300


def cmd_mpc(args: argparse.Namespace) -> int:
    """Co-simulate the plant with the MPC for a model and report the tracking."""

    problems: list[str] = []
    model = load_model(args.model, problems)
    kind = None
    if model is not None:
        try:
            kind = controller_kind(model)
        except OptionError as exc:
            problems.extend(exc.problems or [str(exc)])
    inputs = [args.model] + ([args.plant] if args.plant else [])
    if args.json:
        check_output_path(args.json, inputs, problems)
    if args.plot:  # a folder of figures: checked before the co-simulation runs
        check_output_dir(args.plot, inputs, problems, what="--plot")
    if args.plot and args.json and same_file(args.plot, args.json):
        problems.append("--json and --plot name the same path.")
    if args.horizon is not None and not 1 <= args.horizon <= MAX_HORIZON:
        problems.append(
            f"--horizon must be from 1 to {MAX_HORIZON} samples ({MAX_HORIZON * STEP:g} s), "
            f"found {args.horizon}: the QP grows with the horizon and must be solved within "
            "one 30 ms step."
        )
    if model is not None and abs(model.dt - STEP) > DT_TOLERANCE * STEP:
        problems.append(
            f"model {model.name!r} has sample time {model.dt:g} s; the controller runs at the "
            f"plant's {STEP:g} s step, so it needs a model identified at {STEP:g} s."
        )
    if model is not None:
        # the plant takes forces in N and measures joint angles in rad
        plant_units = {s: "N" for s in model.input_names} | {s: "rad" for s in ("q1", "q2")}
        clash = [
            f"{s.name} [{s.unit}]"
            for s in (*model.inputs, *model.outputs)
            if s.unit and s.name in plant_units and s.unit != plant_units[s.name]
        ]
        if clash:
            problems.append(
                f"model {model.name!r} has {', '.join(clash)}; the plant takes tendon forces in "
                "N and measures joint angles in rad: identify the model from data in those units."
            )
    for name, value in (("--Q", args.Q), ("--R", args.R), ("--speed", args.speed)):
        if value is not None and not (np.isfinite(value) and value > 0):
            problems.append(f"{name} must be > 0, found {value}.")
    reference = None
    try:
        reference = make_reference(
            args.reference,
            duration=args.duration,
            amplitude=args.amplitude / 100.0,
            petals=args.petals,
            speed=args.speed / 100.0,
        )
    except OptionError as exc:
        problems.extend(exc.problems or [str(exc)])
    plant, overrides, params = _plant(args, problems)
    settings = ControllerSettings(
        horizon=args.horizon, Q=args.Q, R=args.R, solver=args.solver, fast=not args.design_path
    )
    raise_problems(problems, "tendonkit mpc cannot run:")
    assert model is not None
    if [n.upper() for n in model.input_names] == ["T1", "T2", "T3", "T4"]:
        warn(
            f"model {model.name!r} maps the measured tensions T1..T4 to the angles; the "
            "controller sends the commanded forces u1..u4, which reach T through the force "
            "controller's lag. Identify MPC models on u1..u4 (docs/tutorial.md, 6)."
        )
    assert model is not None and reference is not None and kind is not None
    return _run(args, model, kind, reference, settings, plant, overrides, params)


def _run(
    args: argparse.Namespace,
    model: Any,
    kind: str,
    reference: Any,
    settings: Any,
    plant: Path | None,
    overrides: dict[str, Any],
    params: dict[str, Any] | None,
) -> int:
    # lazy: keeps this module off tendonkit.fmu until needed
    from tendonkit.fmu.build import cached_plant_fmu

    fmu = plant if plant is not None else cached_plant_fmu(params)
    progress = not args.no_progress and sys.stderr.isatty()
    controller = make_controller(model, settings)
    label = f"{kind} MPC ({model.name})"
    result = run(fmu, reference, controller, parameters=overrides, name=label, progress=progress)
    baseline = (
        open_loop(fmu, reference, parameters=overrides, progress=progress)
        if args.open_loop
        else None
    )
    mpc = result.summary()
    used = {k: getattr(settings, k) for k in ("solver", "fast")}
    used.update(
        {
            k: (DEFAULTS[kind][k] if getattr(settings, k) is None else getattr(settings, k))
            for k in DEFAULTS[kind]
        }
    )
    out: dict[str, Any] = {
        "model": str(args.model),
        "model_kind": model.kind,
        "controller": f"{kind} MPC",
        "model_inputs_as_commands": list(model.input_names),
        "settings": {
            k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in used.items()
        },
        "plant": str(fmu),
        "plant_overrides": overrides,
        "plant_effects": _effects(result.parameters),
        "reference": {
            "kind": reference.name,
            "duration_s": reference.duration,
            "amplitude_m": reference.info["amplitude"],
            "speed_m_per_s": reference.info["speed"],
            "petals": reference.info["petals"],
            "laps": reference.info["laps"],
        },
        "mpc": mpc,
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }
    if baseline is not None:
        ol = baseline.summary()
        out["open_loop"] = ol
        out["improvement_true_percent"] = {
            q: 100.0 * (1.0 - mpc["rms_error_true_rad"][q] / ol["rms_error_true_rad"][q])
            for q in ("q1", "q2")
        }
    figures: list[str] = []
    if args.plot:
        runs = [result] + ([baseline] if baseline is not None else [])
        figures = [str(p) for p in plot_tracking(runs, args.plot)]
    out["figures"] = figures
    if args.json:
        write_json(args.json, out)
    _print(out)
    return 0


def _effects(params: dict[str, Any]) -> list[str]:
    """Names of the hidden effects switched on in a plant's parameters."""
    on = [k[:-3] for k, v in params.items() if k.endswith("_on") and v is True]
    mount = params.get("mount", "none")
    return on + ([f"gravity ({mount})"] if mount not in ("none", "") else [])


def _print(out: dict[str, Any]) -> None:
    mpc = out["mpc"]
    e, et = mpc["rms_error_rad"], mpc["rms_error_true_rad"]
    solve = mpc["solve_time_ms"]
    lines = [
        f"{out['controller']} on {Path(out['plant']).name} (effects: "
        f"{', '.join(out['plant_effects']) or 'none'}), {out['reference']['kind']} "
        f"{out['reference']['duration_s']:.1f} s:",
        f"  RMS joint error q1 {1e3 * e['q1']:.2f} mrad, q2 {1e3 * e['q2']:.2f} mrad "
        f"(true angles: {1e3 * et['q1']:.2f}, {1e3 * et['q2']:.2f} mrad); "
        f"mean end-effector error {mpc['mean_ee_error_cm']:.3f} cm",
        f"  solve time median {solve['median']:.2f} ms, p99 {solve['p99']:.2f} ms, max "
        f"{solve['max']:.2f} ms; deadline misses {mpc['deadline_misses']}; fallbacks "
        f"{mpc['fallbacks']}; input-bound violations {mpc['input_bound_violations']}; "
        f"{mpc['realtime_factor']:.0f}x real time",
    ]
    if "open_loop" in out:
        ol = out["open_loop"]["rms_error_true_rad"]
        imp = out["improvement_true_percent"]
        lines.append(
            f"  open-loop kinematic controller (true angles): q1 {1e3 * ol['q1']:.2f} mrad, "
            f"q2 {1e3 * ol['q2']:.2f} mrad; MPC improvement {imp['q1']:.0f} % / {imp['q2']:.0f} %"
        )
    if out["figures"]:
        lines.append(f"  figures: {', '.join(out['figures'])}")
    print("\n".join(lines))
