"""Architecture contracts: import rules, documented hooks, public API."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

import tendonkit
from tendonkit import hookspecs

ROOT = Path(__file__).resolve().parents[2]


def _imports(path: Path, top_level_only: bool = False) -> set[str]:
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    names: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def _files(folder: str) -> list[Path]:
    return sorted((ROOT / folder).glob("*.py"))


@pytest.mark.parametrize("path", _files("toolkit"), ids=lambda p: p.name)
def test_core_imports_neither_plugins_nor_fmu(path):
    # The CLI modules may import the FMU side lazily (inside functions), never at top level.
    lazy_ok = path.name.startswith("cli") or path.name == "demo.py"
    names = _imports(path, top_level_only=lazy_ok)
    bad = {n for n in names if n.startswith(("tendonkit.plugins", "tendonkit.fmu"))}
    if not lazy_ok:
        bad |= {n for n in names if n.startswith("tendonkit.fmu")}
    assert not bad, f"{path.name} imports {sorted(bad)}"


@pytest.mark.parametrize("path", _files("plugins"), ids=lambda p: p.name)
def test_identifiers_import_no_fmu_or_mpc(path):
    names = _imports(path)
    bad = {
        n
        for n in names
        if n.startswith(("tendonkit.fmu", "tendonkit.mpc", "tendonkit.robot.cosim"))
    }
    assert not bad, f"{path.name} imports {sorted(bad)}"


def test_every_hook_is_documented_and_tested():
    tests = "\n".join(p.read_text() for p in (ROOT / "tests").rglob("test_*.py"))
    docs = "\n".join(p.read_text() for p in (ROOT / "docs").rglob("*.md"))
    hooks = [n for n in dir(hookspecs) if n.startswith("tendonkit_")]
    assert hooks
    for name in hooks:
        doc = inspect.getdoc(getattr(hookspecs, name)) or ""
        assert "Parameters" in doc, f"hook {name} has no numpydoc Parameters section"
        assert name in docs, f"hook {name} is not described in docs/"
        assert name in tests.replace(Path(__file__).read_text(), ""), f"hook {name} has no test"


def test_public_api_is_importable_and_documented():
    for name in tendonkit.__all__:
        obj = getattr(tendonkit, name)
        if callable(obj):
            assert inspect.getdoc(obj), f"tendonkit.{name} has no docstring"


def test_heavy_libraries_are_not_imported_by_the_cli_module():
    import subprocess
    import sys

    code = "import sys, tendonkit.cli; print(sorted(m for m in ('cvxpy','pysindy','fmpy','pythonfmu','control','matplotlib') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
