"""Plugin registration: typed registries, duplicates refused, misspelt hooks caught."""

from __future__ import annotations

import types
from dataclasses import dataclass
from typing import ClassVar

import pytest

from tendonkit import hookimpl
from tendonkit.errors import OptionError, PluginError
from tendonkit.manager import identifiers, register, unregister
from tendonkit.registry import IdentifierRegistry


@dataclass(frozen=True, kw_only=True)
class Dummy:
    name: ClassVar[str] = "dummy"
    description: ClassVar[str] = "A dummy identifier for tests."
    order: int = 2
    gain: float = 1.0
    flags: tuple[int, ...] = (1,)
    fast: bool = False

    def __post_init__(self) -> None:
        if self.order < 1:
            raise OptionError(
                "Invalid options for dummy:", [f"order must be >= 1, found {self.order}."]
            )

    def identify(self, dataset):  # pragma: no cover - not called
        raise NotImplementedError


@pytest.fixture
def temp_plugin():
    names = []

    def add(obj, name):
        names.append(register(obj, name=name))

    yield add
    for n in names:
        unregister(n)


def test_temporary_plugin_is_registered_and_removed(temp_plugin):
    plugin = types.SimpleNamespace(
        tendonkit_register_identifiers=hookimpl(lambda registry: registry.add(Dummy))
    )
    temp_plugin(plugin, "dummy-plugin")
    entry = identifiers().get("dummy")
    assert entry.plugin == "dummy-plugin" and entry.description == "A dummy identifier for tests."
    opts = entry.create(order="3", gain="0.5", flags="1,2,3", fast="yes")
    assert (opts.order, opts.gain, opts.flags, opts.fast) == (3, 0.5, (1, 2, 3), True)


def test_removed_after_fixture():
    assert "dummy" not in identifiers()


def test_duplicate_names_are_refused(temp_plugin):
    plugin = types.SimpleNamespace(
        tendonkit_register_identifiers=hookimpl(lambda registry: registry.add(Dummy, name="arx"))
    )
    temp_plugin(plugin, "clash")
    with pytest.raises(PluginError, match="'arx' from clash is already registered by arx"):
        identifiers()


def test_misspelt_hook_is_refused():
    plugin = types.SimpleNamespace(tendonkit_register_identifier=hookimpl(lambda registry: None))
    with pytest.raises(PluginError, match="unknown hook 'tendonkit_register_identifier'"):
        register(plugin, name="typo")


def test_option_errors_list_every_problem():
    reg = IdentifierRegistry()
    reg.add(Dummy)
    with pytest.raises(OptionError) as info:
        reg.get("dummy").create(order="x", gain="y", nope="1")
    assert len(info.value.problems) == 3


def test_registry_refuses_malformed_identifiers():
    reg = IdentifierRegistry()
    with pytest.raises(PluginError) as info:
        reg.add(object, name="Bad Name")
    assert "lowercase word" in str(info.value) and "no identify" in str(info.value)


def test_unknown_method_lists_registered():
    with pytest.raises(PluginError, match=r"Registered: .*arx"):
        identifiers().get("nosuch")


class _Effect:
    name = "test_friction"
    cause = "coulomb_friction"
    description = "test effect"

    def signature(self, *args, **kwargs):  # pragma: no cover - not called
        return None

    def extend(self, *args, **kwargs):  # pragma: no cover - not called
        return None


def test_effects_hook_registers_typed_effects(temp_plugin):
    from tendonkit.manager import effects

    plugin = types.SimpleNamespace(
        tendonkit_register_effects=hookimpl(lambda registry: registry.add(_Effect()))
    )
    temp_plugin(plugin, "effect-plugin")
    assert effects().get("test_friction").cause == "coulomb_friction"


def test_effect_with_unknown_cause_is_refused():
    from tendonkit.registry import EffectRegistry

    bad = _Effect()
    bad.cause = "gremlins"  # type: ignore[misc]
    with pytest.raises(PluginError, match="cause 'gremlins' is not one of"):
        EffectRegistry().add(bad)
