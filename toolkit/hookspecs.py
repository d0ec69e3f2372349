"""Hook specifications: the complete reference of what a tendonkit plugin can implement.

A plugin is any module or object with functions marked ``@tendonkit.hookimpl`` whose names are
listed here.  Plugins are found through the ``tendonkit`` entry-point group; the built-in
identifiers and effects are registered the same way, from tendonkit's own ``pyproject.toml``.
Implementations may accept fewer arguments than a spec lists (pluggy passes what they ask for),
so hooks can grow without breaking plugins.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from .registry import EffectRegistry, IdentifierRegistry

PROJECT = "tendonkit"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@hookspec
def tendonkit_register_identifiers(registry: IdentifierRegistry) -> None:
    """Register identification methods.

    Call ``registry.add(OptionsClass)`` once per method.  ``OptionsClass`` is a frozen,
    keyword-only dataclass with class attributes ``name`` (lowercase registry name) and
    ``description`` (one line), whose fields are the method's options (validated in
    ``__post_init__``, raising :class:`tendonkit.errors.OptionError`) and whose pure method
    ``identify(dataset) -> Model`` returns a model in the schema.  Names must be unique across
    all plugins; a duplicate is refused with :class:`tendonkit.errors.PluginError`.

    Parameters
    ----------
    registry : IdentifierRegistry
        The registry to add identifiers to.
    """


@hookspec
def tendonkit_register_effects(registry: EffectRegistry) -> None:
    """Register physical effects for ``diagnose``.

    Call ``registry.add(effect)`` once per effect.  An effect is any object satisfying the
    protocol :class:`tendonkit.diagnose.Effect` (module :mod:`tendonkit.diagnose.effect`, the
    whole contract): a ``name``, a ``cause`` from the fixed vocabulary
    (:data:`tendonkit.registry.CAUSES`), ``extend(ctx) -> Extension | None`` returning the
    baseline extended with the matching structure (parameters estimated from the training data
    in ``ctx``), and ``signature(ctx, baseline, valid, residuals) -> dict``, the evidence shown
    in the report.  Optionally it also satisfies :class:`tendonkit.diagnose.DirectTest`:
    ``direct_test(ctx, extension, valid)`` tests the signature on the validation data where the
    extension puts it and returns a dict with a ``p_value`` (or None); diagnose then accepts the
    finding on either route, Bonferroni-corrected (``docs/diagnose.md``, *Direct evidence*).

    Parameters
    ----------
    registry : EffectRegistry
        The registry to add effects to.
    """
