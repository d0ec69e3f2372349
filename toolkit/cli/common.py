"""What every ``tendonkit`` subcommand shares: the one-message error style and safe output.

The file rules (inputs are regular files, outputs are written atomically and never over an
input) are :mod:`tendonkit.files`; they are re-exported here for the commands.

Every user error (arguments, files, data, options) becomes one :class:`UsageError` listing every
problem found; :func:`tendonkit.cli.main` prints it on standard error and exits with status 2.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any, ClassVar

from ..dataset import split_header
from ..errors import OptionError, SchemaError, TendonkitError
from ..files import (
    atomic_write,
    check_input_file,
    check_output_dir,
    check_output_path,
    prepare_output_dir,
    same_file,
    write_json,
)
from ..manager import identifiers
from ..schema import Model

EXIT_USAGE = 2

__all__ = [
    "EXIT_USAGE",
    "Parser",
    "UsageError",
    "atomic_write",
    "check_input_file",
    "check_output_dir",
    "check_output_path",
    "csv_header",
    "identifier_arguments",
    "load_model",
    "noted",
    "output_dirs",
    "parse_key_values",
    "positive_float",
    "prepare_output_dir",
    "raise_problems",
    "same_file",
    "seed_argument",
    "split_names",
    "write_json",
]


class UsageError(TendonkitError, ValueError):
    """Command-line arguments that cannot work together."""


#: A value argparse could not convert or check (its problem is in :attr:`Parser.bad_values`).
_UNPARSED = object()


class Parser(argparse.ArgumentParser):
    """argparse that reports errors in tendonkit's one-message style (exit 2).

    argparse stops at the first value it cannot convert or that is not among an option's
    choices; here every such value is collected (:attr:`bad_values`, shared by a command and
    its subcommands) and they are reported together: by :meth:`error` when argparse stops for
    another reason, else by :meth:`report_bad_values` once the arguments are parsed.
    """

    #: Problems of the values parsed so far (class-level: one parse spans the subparsers; the
    #: command line is parsed in one thread).
    bad_values: ClassVar[list[str]] = []
    _depth: ClassVar[int] = 0

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        """The outermost parse (a subcommand's is nested in it) starts with no problems and
        reports the values it could not use, also when argparse itself ends early (--help)."""
        outer = Parser._depth == 0
        if outer:
            Parser.bad_values.clear()
        Parser._depth += 1
        try:
            result = super().parse_known_args(args, namespace)
        except BaseException:
            if outer:
                Parser.bad_values.clear()
            raise
        finally:
            Parser._depth -= 1
        if outer:
            self.report_bad_values()
        return result

    def _get_value(self, action: argparse.Action, arg_string: str) -> Any:
        try:
            return super()._get_value(action, arg_string)  # type: ignore[misc]
        except argparse.ArgumentError as exc:
            Parser.bad_values.append(str(exc))
            return _UNPARSED

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        if value is _UNPARSED:
            return
        try:
            super()._check_value(action, value)  # type: ignore[misc]
        except argparse.ArgumentError as exc:
            if isinstance(action, argparse._SubParsersAction):
                raise  # an unknown command: argparse's own message
            Parser.bad_values.append(str(exc))

    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        problems = [*Parser.bad_values, message]
        Parser.bad_values.clear()
        if len(problems) == 1:
            print(f"tendonkit: error: {message}", file=sys.stderr)
        else:
            listed = "".join(f"\n  - {p}" for p in problems)
            print(f"tendonkit: error: the arguments cannot be used:{listed}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)

    def report_bad_values(self) -> None:
        """Exit 2 listing every value that could not be converted or checked, if any."""
        if Parser.bad_values:
            problems = list(Parser.bad_values)
            Parser.bad_values.clear()
            listed = "".join(f"\n  - {p}" for p in problems)
            print(f"tendonkit: error: the arguments cannot be used:{listed}", file=sys.stderr)
            raise SystemExit(EXIT_USAGE)


#: Largest seed accepted (numpy's generators take any non-negative integer; 2**63 - 1 keeps
#: seeds portable across languages and file formats).
MAX_SEED = 2**63 - 1


def seed_argument(text: str) -> int:
    """argparse type of ``--seed``: an integer from 0 to 2**63 - 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a seed is a whole number >= 0, found {text!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(
            f"a seed is a whole number from 0 to 2**63-1, found {value}"
        )
    return value


def positive_float(text: str) -> float:
    """argparse type of a finite number > 0 (durations, laps)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, found {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, found {text}")
    return value


@contextmanager
def output_dirs(*paths: str | Path | None) -> Iterator[None]:
    """Create the output folders (checked by ``check_output_dir``) for the work in the block.

    A folder created here is removed again when the block fails and left it empty, so a failed
    command leaves nothing behind.
    """
    created = [Path(p) for p in paths if p is not None and not Path(p).exists()]
    for p in paths:
        if p is not None:
            prepare_output_dir(p)
    try:
        yield
    except BaseException:
        for p in created:
            with suppress(OSError):
                p.rmdir()  # only when empty
        raise


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


def csv_header(path: str | Path) -> list[str]:
    """Column names of a CSV file (empty if unreadable; the loader reports why)."""
    if not check_input_file(path, []):
        return []  # the loader reports why
    try:
        with Path(path).open(newline="", encoding="utf-8-sig") as fh:
            return [split_header(h)[0] for h in next(csv.reader(fh), [])]
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def warn(text: str) -> None:
    """Print a warning as every command does: ``tendonkit: warning: <text>`` on stderr."""
    print(f"tendonkit: warning: {text}", file=sys.stderr)


def raise_problems(problems: list[str], headline: str = "The command cannot run:") -> None:
    """Raise one :class:`UsageError` listing all problems, if any."""
    if problems:
        raise UsageError(headline, problems)


def load_model(path: str, problems: list[str]) -> Model | None:
    """Load a model JSON file, appending why it cannot be loaded to ``problems``."""
    try:
        return Model.load(path)
    except SchemaError as exc:
        problems.append(str(exc).replace("\n", "\n   "))
        return None


def identifier_arguments(
    args: argparse.Namespace, problems: list[str]
) -> tuple[list[str], list[str], dict[str, str], Any]:
    """``--inputs``, ``--outputs``, ``--method`` and ``--option``: names, options, options object.

    Every problem is appended to ``problems``; the options object is None when the method or
    its options are invalid.
    """
    inputs, outputs = split_names(args.inputs), split_names(args.outputs)
    for flag, text, names in (
        ("--inputs", args.inputs, inputs),
        ("--outputs", args.outputs, outputs),
    ):
        if not names:
            problems.append(f"{flag} names no column.")
        elif len(names) < len((text or "").split(",")):
            problems.append(f"{flag} {text!r} has an empty name (two commas, or one at an end).")
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


def noted(model: Any, text: str) -> Any:
    """``model`` with ``text`` appended to its provenance notes."""
    prov = model.provenance
    notes = f"{prov.notes}; {text}" if prov.notes else text
    return model.replace(provenance=dataclasses.replace(prov, notes=notes))
