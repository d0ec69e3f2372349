"""A third-party effect, found through an entry point, is tried and named by diagnose.

The example package in docs/example-effect-plugin is made importable and given installed-package
metadata in a temporary folder on ``sys.path`` — what ``pip install`` would leave — so discovery
goes through ``importlib.metadata`` and pluggy, with no change to tendonkit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import tendonkit as tk
from tendonkit import manager
from tendonkit.dataset import Dataset
from tendonkit.diagnose import DirectTest, Effect, diagnose

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "example-effect-plugin"


@pytest.fixture
def installed_effect(tmp_path, monkeypatch):
    dist = tmp_path / "tendonkit_cubic_spring-0.1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: tendonkit-cubic-spring\nVersion: 0.1.0\n"
    )
    (dist / "entry_points.txt").write_text("[tendonkit]\ncubic_spring = tendonkit_cubic_spring\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(EXAMPLE / "src"))
    manager.plugin_manager.cache_clear()
    yield
    sys.modules.pop("tendonkit_cubic_spring", None)
    manager.plugin_manager.cache_clear()


def _duffing(n: int, seed: int) -> Dataset:
    """A hardening spring: the truth is a cubic stiffness."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=n)
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.6 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * u[k - 1] - 2.0 * y[k - 1] ** 3
    y += 0.01 * y.std() * rng.normal(size=n)
    return Dataset.from_arrays(u[:, None], y[:, None], dt=0.01, inputs=["force"], outputs=["pos"])


def test_the_entry_point_effect_is_registered_and_satisfies_the_protocol(installed_effect):
    effects = tk.effects()
    assert "cubic_spring" in effects.names()
    effect = effects.get("cubic_spring")
    assert isinstance(effect, Effect) and not isinstance(effect, DirectTest)
    assert effect.cause == "nonlinear_stiffness"


def test_diagnose_tries_and_names_the_third_party_effect(installed_effect):
    train, valid = _duffing(3000, 1), _duffing(1500, 2)
    d = diagnose(train, valid, options={"na": 2, "nb": 1}, effects=["cubic_spring"])
    assert d.named_effect == "cubic_spring" and d.cause == "nonlinear_stiffness"
    assert d.best is not None and d.best.gain > 10
    # among every registered effect it is tried too, and counts as significant evidence
    d_all = diagnose(train, valid, options={"na": 2, "nb": 1})
    tried = {f.effect: f for f in d_all.findings}
    assert "cubic_spring" in tried and tried["cubic_spring"].significant
    assert d_all.cause == "nonlinear_stiffness"
