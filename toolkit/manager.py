"""The plugin manager: finds plugins through entry points and fills the registries."""

from __future__ import annotations

import functools
import warnings
from importlib import metadata
from typing import Any

import pluggy

from . import hookspecs
from .errors import PluginError
from .registry import EffectRegistry, IdentifierRegistry

ENTRY_POINT_GROUP = "tendonkit"


#: Plugins that failed to load, ``(entry point name, reason)``; reported by ``tendonkit plugins``.
FAILURES: list[tuple[str, str]] = []


@functools.cache
def plugin_manager() -> pluggy.PluginManager:
    """The process-wide plugin manager with every installed plugin loaded.

    Each entry point of the ``tendonkit`` group is loaded on its own: a plugin that cannot be
    imported, or that implements a hook not in :mod:`tendonkit.hookspecs` (a misspelt name,
    caught by ``check_pending``), is left out with a warning and listed in :data:`FAILURES`,
    so one broken third-party plugin never disables the others.
    """
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    FAILURES.clear()
    for ep in sorted(metadata.entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        if pm.get_plugin(ep.name) is not None or pm.is_blocked(ep.name):
            continue
        try:
            plugin = ep.load()
            pm.register(plugin, name=ep.name)
            _check_one(pm, ep.name)
        except Exception as exc:  # a third-party plugin may raise anything on import
            FAILURES.append((ep.name, f"{type(exc).__name__}: {exc}"))
            warnings.warn(
                f"tendonkit plugin {ep.name!r} ({ep.value}) was not loaded: {exc}",
                RuntimeWarning,
                stacklevel=2,
            )
    return pm


def _check_one(pm: pluggy.PluginManager, name: str) -> None:
    """Unregister and raise if plugin ``name`` implements an unknown hook."""
    plugin = pm.get_plugin(name)
    for hook_name in dir(plugin):
        if hook_name.startswith(hookspecs.PROJECT + "_") and not hasattr(hookspecs, hook_name):
            pm.unregister(name=name)
            raise PluginError(
                f"implements unknown hook {hook_name!r}; known hooks: "
                + ", ".join(h for h in dir(hookspecs) if h.startswith(hookspecs.PROJECT + "_"))
            )
    try:
        pm.check_pending()
    except pluggy.PluginValidationError as exc:
        pm.unregister(name=name)
        raise PluginError(str(exc)) from None


def register(plugin: Any, name: str | None = None) -> str:
    """Register a plugin object (module or instance) at run time; returns its name."""
    pm = plugin_manager()
    try:
        registered = pm.register(plugin, name=name) or ""
        _check_one(pm, registered)
    except (ValueError, pluggy.PluginValidationError) as exc:
        raise PluginError(f"Cannot register plugin {name or plugin!r}: {exc}") from None
    except PluginError as exc:
        raise PluginError(f"Cannot register plugin {name or plugin!r}: {exc}") from None
    return registered


def unregister(name: str) -> None:
    """Remove a plugin registered with :func:`register`."""
    plugin_manager().unregister(name=name)


def _fill(registry: IdentifierRegistry | EffectRegistry, hook_name: str) -> None:
    pm = plugin_manager()
    hook = getattr(pm.hook, hook_name)
    for impl in hook.get_hookimpls():  # registration order (pluggy calls LIFO; we do not)
        registry._current_plugin = impl.plugin_name
        available = {"registry": registry}
        impl.function(*[available[a] for a in impl.argnames])
    registry._current_plugin = "?"


def identifiers() -> IdentifierRegistry:
    """A registry with every registered identifier."""
    reg = IdentifierRegistry()
    _fill(reg, "tendonkit_register_identifiers")
    return reg


def effects() -> EffectRegistry:
    """A registry with every registered effect."""
    reg = EffectRegistry()
    _fill(reg, "tendonkit_register_effects")
    return reg
