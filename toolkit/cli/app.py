"""The ``tendonkit`` command line: one subcommand per step of the data flow.

Every user error (arguments, files, data, options) becomes one message that lists every problem
found, on standard error, with exit status 2 — never a traceback.  The subcommands live in one
module per group: ``models`` (identify, simulate, compare), ``diagnose``, ``robot`` (plant build,
collect, demo), ``export``, ``mpc`` and ``campaign``; their shared helpers in ``common``.  Heavy libraries
(fmpy, pythonfmu, cvxpy, pysindy, matplotlib) are imported inside the commands that need them, so
``tendonkit --help`` is instant.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .. import __version__
from ..errors import TendonkitError
from ..manager import FAILURES, effects, identifiers, plugin_manager
from . import campaign, diagnose, export, models, mpc, robot
from .common import EXIT_USAGE, Parser, check_output_path, raise_problems, write_json


def cmd_plugins(args: argparse.Namespace) -> int:
    """List registered identifiers and effects."""
    problems: list[str] = []
    if args.json:
        check_output_path(args.json, [], problems, what="--json")
    raise_problems(problems, "tendonkit plugins cannot run:")
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
        for eff in effs:
            print(f"  {eff.name.ljust(width)}  [{eff.cause}] {getattr(eff, 'description', '')}")
    for name, reason in FAILURES:
        print(f"not loaded: {name}: {reason}", file=sys.stderr)
    return 0


def build_parser() -> Parser:
    """The argument parser of the ``tendonkit`` command."""
    parser = Parser(
        prog="tendonkit",
        description="Identify, diagnose, export and control dynamic models of a "
        "tendon-actuated continuum robot.",
    )
    parser.add_argument("--version", action="version", version=f"tendonkit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)

    models.add_commands(sub)
    diagnose.add_commands(sub)

    p = sub.add_parser("plugins", help="list registered identifiers and effects")
    p.add_argument("--json", help="write the list as JSON here")
    p.set_defaults(func=cmd_plugins)

    robot.add_commands(sub)
    export.add_commands(sub)
    mpc.add_commands(sub)
    campaign.add_commands(sub)
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
    except OSError as exc:
        # a file or folder the system refuses (permissions, a read-only disk, a name taken by
        # a file) that no check foresaw: the user's to fix, so one message, never a traceback
        where = f" {exc.filename!r}" if exc.filename else ""
        print(f"tendonkit: error: cannot use{where}: {exc.strerror or exc}.", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("tendonkit: interrupted", file=sys.stderr)
        return 130
