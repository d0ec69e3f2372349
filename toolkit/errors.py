"""Errors raised by tendonkit.

Every error derives from :class:`TendonkitError`; subclasses also inherit the built-in
exception they refine, so ``except ValueError`` keeps working for callers who do not know
tendonkit.  Messages say what was expected and what was found, and list every problem at once.
"""

from __future__ import annotations

from collections.abc import Iterable


class TendonkitError(Exception):
    """Base class of every error tendonkit raises on purpose."""

    def __init__(self, message: str, problems: Iterable[str] | None = None) -> None:
        self.problems: list[str] = list(problems) if problems is not None else []
        if self.problems:
            bullet = "\n".join(f"  - {p}" for p in self.problems)
            message = f"{message}\n{bullet}"
        super().__init__(message)


class DataError(TendonkitError, ValueError):
    """Input data (CSV file or arrays) is malformed or unsuitable."""


class SchemaError(TendonkitError, ValueError):
    """A model file or model object does not follow the model schema."""


class OptionError(TendonkitError, ValueError):
    """An option given to an identifier, effect or command is invalid."""


class PluginError(TendonkitError, LookupError):
    """A plugin is unknown, registered twice, or broken."""


class SimulationError(TendonkitError, RuntimeError):
    """A simulation or co-simulation could not be carried out."""


class FMUError(TendonkitError, RuntimeError):
    """Building, validating or running an FMU failed."""


class OutputError(TendonkitError, OSError):
    """An output file or folder cannot be written (refused, or the system failed to write it)."""


class TendonkitWarning(UserWarning):
    """A result that may be wrong although nothing failed (a model that explains its own
    training data no better than their mean)."""


def raise_if(problems: list[str], cls: type[TendonkitError], headline: str) -> None:
    """Raise ``cls`` listing ``problems`` when there are any.

    Parameters
    ----------
    problems : list of str
        Problems found so far; nothing happens when empty.
    cls : type
        The error class to raise.
    headline : str
        The first line of the message.
    """
    if problems:
        raise cls(headline, problems)
