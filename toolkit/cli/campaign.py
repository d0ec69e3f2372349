"""The ``tendonkit campaign`` subcommand: a controller checked across many plant variants.

:func:`add_commands` is called by :func:`tendonkit.cli.app.build_parser`.  The spec is a TOML file
(docs/campaigns.md); the runs go to a local process pool (``--jobs``, default: every core), to
this process (``--jobs 1``) or to a Dask cluster (``--scheduler ADDRESS``, or ``local`` for a
LocalCluster).  Running the same command again after an interruption resumes from the rows
already written.  Exit status: 0 when the pass rate reaches the spec's ``min_pass_rate``, 1 when it
does not, 2 for a bad spec or bad arguments (every problem listed).

Examples
--------
::

    tendonkit campaign robustness.toml --out robustness --jobs 2
    tendonkit campaign robustness.toml --out robustness --scheduler tcp://10.0.0.5:8786
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import OptionError
from ..parallel import default_jobs, task_problems
from ..robot.campaign import load_spec, run_campaign, user_class_problems
from ..robot.campaign_report import render
from .common import check_output_dir, check_output_path, raise_problems, same_file, write_json

__all__ = ["add_commands", "cmd_campaign"]


def add_commands(sub: Any) -> None:
    """Add the ``campaign`` subcommand to the ``tendonkit`` subparsers."""
    p = sub.add_parser(
        "campaign",
        help="co-simulate controllers across many plant draws (pass rate, worst cases, report)",
        description="Run a co-simulation campaign from a TOML spec: plant draws x noise seeds x "
        "references x controllers, each run one co-simulation with the plant FMU; write a "
        "table (runs.csv), a summary (summary.json) and an HTML report.  An interrupted "
        "campaign resumes from the rows already written when run again.",
    )
    p.add_argument("spec", help="campaign spec (TOML, docs/campaigns.md)")
    p.add_argument("--out", help="campaign folder (default: the spec's name beside it)")
    p.add_argument(
        "--jobs",
        type=int,
        help=f"worker processes (default: the machine's cores, here {default_jobs()}; "
        "1 runs in this process)",
    )
    p.add_argument(
        "--scheduler",
        help="run on dask.distributed: 'local' (a LocalCluster of --jobs workers) or a "
        "scheduler address such as tcp://host:8786 (pip install 'tendonkit[cluster]')",
    )
    p.add_argument(
        "--fresh",
        action="store_true",
        help="set aside the rows of an earlier run in --out (kept as runs-*.jsonl.old) "
        "instead of resuming from them",
    )
    p.add_argument("--no-report", action="store_true", help="no figures and no index.html")
    p.add_argument("--json", help="also write the summary as JSON here")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_campaign)


def _read_by(spec: Any, path: str) -> list[str | Path]:
    """The files a campaign reads: its spec, its models and its python controllers' modules."""
    read: list[str | Path] = [path]
    for c in spec.controllers if spec is not None else ():
        if c.model:
            read.append(c.model)
        if c.kind == "python" and c.cls:
            module = str(c.cls).partition(":")[0].replace(".", "/")
            base = Path(c.path) if c.path else Path(path).resolve().parent
            read += [base / f"{module}.py", base / module / "__init__.py"]
    return read


def cmd_campaign(args: argparse.Namespace) -> int:
    """Run the campaign; 0 when it passes, 1 when its pass rate is below the spec's minimum."""
    problems: list[str] = []
    spec = None
    try:
        spec = load_spec(args.spec, check_classes=False)  # the user's classes: last, below
    except OptionError as exc:
        problems.append(str(exc).replace("\n", "\n   "))
    # the engine's own checks, named as the options are named here
    problems += [
        p if p.startswith("a dask") else f"--{p}" for p in task_problems(args.jobs, args.scheduler)
    ]
    out = Path(args.out) if args.out else None
    if out is None and spec is not None:
        out = Path(args.spec).resolve().parent / f"{spec.name.replace(' ', '_')}-campaign"
    if out is not None:
        check_output_dir(out, [args.spec], problems, what="--out")
    if args.json:
        # never over the spec, a model or a controller's module it reads, nor the --out folder
        check_output_path(args.json, _read_by(spec, args.spec), problems, what="--json")
        if out is not None and same_file(args.json, out):
            problems.append("--json and --out name the same path.")
    if not problems and spec is not None:
        # the user's controller modules run when imported: only once nothing else is wrong
        problems += user_class_problems(spec)
    raise_problems(problems, "tendonkit campaign cannot run:")
    assert spec is not None and out is not None
    print(
        f"campaign {spec.name}: {spec.n_runs} runs ({spec.n_draws} plant draws x {spec.repeats} "
        f"noise seed(s) x {len(spec.references)} reference(s) x {len(spec.controllers)} "
        f"controller(s)) -> {out}",
        file=sys.stderr,
    )
    try:
        result = run_campaign(
            spec,
            out,
            jobs=args.jobs,
            scheduler=args.scheduler,
            fresh=args.fresh,
            progress=not args.no_progress and sys.stderr.isatty(),
            report=not args.no_report,
        )
    except KeyboardInterrupt:
        print(
            f"tendonkit: interrupted; the finished runs are in {out / 'runs.jsonl'}: run the same "
            "command again to resume.",
            file=sys.stderr,
        )
        return 130
    print(render(result.summary))
    print(
        f"  table: {out / 'runs.csv'}"
        + ("" if args.no_report else f"; report: {out / 'index.html'}")
    )
    if args.json:
        write_json(args.json, result.summary)
    return 0 if result.passed else 1
