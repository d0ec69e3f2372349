"""A third-party identifier, found through an entry point, works end to end with no core change.

The example package in docs/example-plugin is made importable and given installed-package
metadata (a ``.dist-info`` with ``entry_points.txt``) in a temporary folder on ``sys.path`` —
exactly what ``pip install`` would leave — so discovery goes through ``importlib.metadata``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import tendonkit as tk
from tendonkit import manager
from tendonkit.compare import compare

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "example-plugin"


@pytest.fixture
def installed_example(tmp_path, monkeypatch):
    dist = tmp_path / "tendonkit_fir-0.1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: tendonkit-fir\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text("[tendonkit]\nfir = tendonkit_fir\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    manager.plugin_manager.cache_clear()
    yield
    sys.modules.pop("tendonkit_fir", None)
    manager.plugin_manager.cache_clear()


def test_entry_point_identifier_identify_simulate_compare(installed_example, small_data):
    _, train, valid = small_data
    assert "fir" in tk.identifiers()
    assert tk.identifiers().get("fir").plugin == "fir"
    model = tk.identify(train, "fir", n=80)
    assert model.kind == "arx" and model.provenance.identifier == "fir"
    e = valid.experiments[0]
    y = tk.simulate(model, e.u, y=e.y)
    assert y.shape == e.y.shape
    result = compare([model], valid)
    assert result["models"][0]["mean_fit"] > 80  # a long FIR captures this well-damped system


def test_example_plugin_passes_the_conformance_suite(installed_example):
    from tendonkit.testing import check_identifier

    check_identifier(tk.identifiers().get("fir").create(n=40))
