"""The public conformance suite runs over every registered identifier."""

from __future__ import annotations

import pytest

from tendonkit.manager import identifiers
from tendonkit.testing import identifier_checks

CHECKS = identifier_checks()


def _cases():
    reg = identifiers()
    return [(e.name, c) for e in reg for c in CHECKS]


@pytest.mark.parametrize(
    ("method", "check"), _cases(), ids=lambda v: v if isinstance(v, str) else v.__name__
)
def test_identifier_conforms(method, check):
    check(identifiers().get(method).create())


def test_all_builtins_are_registered_through_entry_points():
    reg = identifiers()
    assert {"n4sid", "arx", "sindyc"} <= set(reg.names())
    for name in ("n4sid", "arx", "sindyc"):
        assert reg.get(name).plugin == name  # the entry point name, not a core list


def test_suite_catches_a_broken_identifier():
    """The suite is not vacuous: an identifier that ignores the data fails it."""
    from dataclasses import dataclass
    from typing import ClassVar

    import numpy as np

    from tendonkit.identification import build_model
    from tendonkit.schema import StateSpace

    @dataclass(frozen=True, kw_only=True)
    class Lazy:
        name: ClassVar[str] = "lazy"
        description: ClassVar[str] = "returns a zero model"

        def identify(self, dataset):
            n = 1
            rep = StateSpace(
                np.zeros((n, n)),
                np.zeros((n, dataset.nu)),
                np.zeros((dataset.ny, n)),
                np.zeros((dataset.ny, dataset.nu)),
            )
            return build_model(self, dataset, rep)

    failed = set()
    for check in CHECKS:
        try:
            check(Lazy())
        except AssertionError:
            failed.add(check.__name__)
    # no error for tiny data, and a fit far below the threshold; every other check passes
    assert failed == {"check_shape_errors", "check_simulate_and_compare"}, failed
