"""Typed registries filled by plugins through the hooks in :mod:`tendonkit.hookspecs`."""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from .errors import OptionError, PluginError

if TYPE_CHECKING:  # the contract lives with diagnose; the core never imports it at run time
    from .diagnose.effect import Effect

#: The fixed vocabulary of physical causes ``diagnose`` can name.
CAUSES: tuple[str, ...] = (
    "coulomb_friction",
    "backlash",
    "hysteresis",
    "input_delay",
    "dead_zone",
    "saturation",
    "actuator_lag",
    "nonlinear_stiffness",
    "gravity",
    "static_nonlinearity",
    "none",
)


@runtime_checkable
class Identifier(Protocol):
    """What an identifier options object provides (see :mod:`tendonkit.hookspecs`)."""

    name: typing.ClassVar[str]
    description: typing.ClassVar[str]

    def identify(self, dataset: Any) -> Any:
        """Identify a :class:`~tendonkit.schema.Model` from a :class:`~tendonkit.dataset.Dataset`."""
        ...


@dataclass(frozen=True)
class IdentifierEntry:
    """A registered identifier: its name, one-line description, options class and origin."""

    name: str
    description: str
    factory: type
    plugin: str

    def create(self, **options: Any) -> Any:
        """Instantiate the options object, converting text values (from the CLI) to field types."""
        return create_options(self.factory, options)

    @property
    def options(self) -> dict[str, Any]:
        """Option names and their defaults."""
        return {
            f.name: (f.default if f.default is not dataclasses.MISSING else None)
            for f in dataclasses.fields(self.factory)
        }


class IdentifierRegistry:
    """Identifiers registered by plugins, by lowercase name."""

    def __init__(self) -> None:
        self._entries: dict[str, IdentifierEntry] = {}
        self._current_plugin = "?"

    def add(
        self, factory: type, *, name: str | None = None, description: str | None = None
    ) -> None:
        """Register an identifier options class.

        Raises
        ------
        PluginError
            If the name is taken, not lowercase, or the class lacks ``identify``.
        """
        name = name or getattr(factory, "name", None)
        description = description or getattr(factory, "description", "") or ""
        problems = []
        if not isinstance(name, str) or not name or name != name.lower() or " " in name:
            problems.append(f"identifier name must be a lowercase word, found {name!r}.")
        if not callable(getattr(factory, "identify", None)):
            problems.append(f"{factory!r} has no identify(dataset) method.")
        if not dataclasses.is_dataclass(factory):
            problems.append(f"{factory!r} must be a (frozen, keyword-only) dataclass of options.")
        if isinstance(name, str) and name in self._entries:
            other = self._entries[name].plugin
            problems.append(
                f"identifier {name!r} from {self._current_plugin} is already registered by {other}."
            )
        if problems:
            raise PluginError("Cannot register identifier:", problems)
        assert isinstance(name, str)
        self._entries[name] = IdentifierEntry(
            name,
            description.strip().splitlines()[0] if description else "",
            factory,
            self._current_plugin,
        )

    def get(self, name: str) -> IdentifierEntry:
        """The entry for ``name``; unknown names list the registered ones."""
        try:
            return self._entries[name]
        except KeyError:
            raise PluginError(
                f"Unknown identification method {name!r}. Registered: {', '.join(sorted(self._entries))}."
            ) from None

    def __iter__(self) -> Iterator[IdentifierEntry]:
        return iter(sorted(self._entries.values(), key=lambda e: e.name))

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> list[str]:
        """Registered names, sorted."""
        return sorted(self._entries)


class EffectRegistry:
    """Effects registered by plugins, by name; each names a cause from :data:`CAUSES`.

    An effect is any object satisfying :class:`tendonkit.diagnose.Effect` (``name``, ``cause``,
    ``extend``, ``signature``; optionally :class:`tendonkit.diagnose.DirectTest`).
    """

    def __init__(self) -> None:
        self._entries: dict[str, Effect] = {}
        self._origin: dict[str, str] = {}
        self._current_plugin = "?"

    def add(self, effect: Effect) -> None:
        """Register an effect (:class:`tendonkit.diagnose.Effect`); every problem is reported."""
        name = getattr(effect, "name", None)
        cause = getattr(effect, "cause", None)
        problems = []
        if not isinstance(name, str) or not name:
            problems.append(f"effect {effect!r} has no name.")
        if cause not in CAUSES or cause == "none":
            problems.append(f"effect {name!r}: cause {cause!r} is not one of {list(CAUSES[:-1])}.")
        for method in ("signature", "extend"):
            if not callable(getattr(effect, method, None)):
                problems.append(f"effect {name!r} has no {method}() method.")
        if isinstance(name, str) and name in self._entries:
            problems.append(f"effect {name!r} is already registered by {self._origin[name]}.")
        if problems:
            raise PluginError("Cannot register effect:", problems)
        assert isinstance(name, str)
        self._entries[name] = effect
        self._origin[name] = self._current_plugin

    def get(self, name: str) -> Effect:
        """The effect called ``name``."""
        try:
            return self._entries[name]
        except KeyError:
            raise PluginError(
                f"Unknown effect {name!r}. Registered: {', '.join(sorted(self._entries))}."
            ) from None

    def __iter__(self) -> Iterator[Effect]:
        return iter(self._entries[k] for k in sorted(self._entries))

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> list[str]:
        """Registered names, sorted."""
        return sorted(self._entries)


# -- option coercion (CLI text -> typed dataclass fields) ---------------------------------------


def create_options(factory: type, options: dict[str, Any]) -> Any:
    """Build ``factory(**options)``, converting strings to the annotated field types.

    Every unknown or unconvertible option is reported in one :class:`OptionError`.
    """
    fields = {f.name: f for f in dataclasses.fields(factory) if f.init}
    hints = typing.get_type_hints(factory)
    problems = []
    values: dict[str, Any] = {}
    for key, raw in options.items():
        if key not in fields:
            problems.append(
                f"unknown option {key!r} for {getattr(factory, 'name', factory.__name__)}; "
                f"options: {', '.join(sorted(fields)) or '(none)'}."
            )
            continue
        try:
            values[key] = _coerce(raw, hints.get(key, Any))
        except (TypeError, ValueError):
            problems.append(
                f"option {key}={raw!r} is not a valid {_type_name(hints.get(key, Any))}."
            )
    if problems:
        # Validate the options that did convert too (the others at their defaults), so that
        # every problem is reported at once.
        try:
            factory(**values)
        except OptionError as exc:
            problems.extend(exc.problems or [str(exc)])
        except TypeError:
            pass
        raise OptionError(
            f"Invalid options for {getattr(factory, 'name', factory.__name__)}:", problems
        )
    try:
        return factory(**values)
    except OptionError:
        raise
    except TypeError as exc:
        raise OptionError(f"Invalid options for {getattr(factory, 'name', '?')}: {exc}") from None


#: How an option's type reads in a message.
_PLAIN = {int: "whole number", float: "number", bool: "true/false", str: "text"}


def _type_name(tp: Any) -> str:
    """An option's type in words: ``int | Literal['auto']`` -> ``whole number or 'auto'``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        names = [_type_name(a) for a in args if a is not type(None)]
        names += ["none"] if type(None) in args else []
        return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]
    if origin is typing.Literal:
        return " or ".join(repr(a) for a in args)
    if origin in (tuple, list) and args:
        return f"{origin.__name__} of {_type_name(args[0])}s"
    if tp in _PLAIN:
        return _PLAIN[tp]
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(raw: Any, tp: Any) -> Any:
    if not isinstance(raw, str):
        return raw
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if type(None) in args and raw.strip().lower() in ("none", "null", ""):
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(raw, arg)
            except (TypeError, ValueError):
                continue
        raise ValueError(raw)
    if origin is typing.Literal:
        for arg in typing.get_args(tp):
            if str(arg) == raw:
                return arg
        raise ValueError(raw)
    if origin is tuple:
        args = typing.get_args(tp)
        inner = args[0] if args else str
        return tuple(_coerce(part.strip(), inner) for part in raw.split(",") if part.strip())
    if tp is bool:
        low = raw.strip().lower()
        if low in ("1", "true", "yes", "on"):
            return True
        if low in ("0", "false", "no", "off"):
            return False
        raise ValueError(raw)
    if tp is int:
        return int(raw)
    if tp is float:
        return float(raw)
    if tp is str or tp is Any:
        return raw
    raise TypeError(tp)
