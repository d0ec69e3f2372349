"""The module paths of tendonkit 0.1 import for one release, with a DeprecationWarning."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

from tendonkit import _compat


@pytest.mark.parametrize("old", sorted(_compat.MOVED_MODULES))
def test_every_old_path_imports_with_a_warning_naming_the_new_one(old):
    new = _compat.MOVED_MODULES[old]
    homes = [new] if isinstance(new, str) else list(new)
    code = (
        "import warnings, importlib, sys\n"
        "warnings.simplefilter('always')\n"
        "with warnings.catch_warnings(record=True) as w:\n"
        f"    m = importlib.import_module({old!r})\n"
        "print([str(x.message) for x in w if x.category is DeprecationWarning])\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert old in r.stdout and all(h in r.stdout for h in homes)
    module = importlib.import_module(old)
    seen: set[str] = set()
    for home in homes:
        target = importlib.import_module(home)
        public = getattr(target, "__all__", None) or [n for n in vars(target) if n[0] != "_"]
        for name in [n for n in public if n not in seen]:
            assert getattr(module, name) is getattr(target, name), name
        seen.update(vars(target))


def test_split_module_finds_names_in_either_home():
    from tendonkit.diagnose.clip import atom_test
    from tendonkit.diagnose.stats import holm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        stats = importlib.import_module("tendonkit.stats")
    assert stats.atom_test is atom_test and stats.holm is holm
    with pytest.raises(AttributeError):
        _ = stats.not_a_name


def test_names_that_left_figures_resolve_with_a_warning():
    from tendonkit.robot import figures as robot_figures

    with pytest.warns(DeprecationWarning, match=r"tendonkit\.robot\.figures\.fig2"):
        from tendonkit.figures import fig2
    assert fig2 is robot_figures.fig2
    with pytest.raises(ImportError):
        from tendonkit.figures import no_such_figure  # noqa: F401


def test_unknown_old_paths_still_fail():
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("tendonkit.no_such_module")
