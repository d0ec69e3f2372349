"""Architecture contracts: documented hooks, public API, an instant ``--help``."""

from __future__ import annotations

import inspect
from pathlib import Path

import tendonkit
from tendonkit import hookspecs

ROOT = Path(__file__).resolve().parents[2]


# The import rules of the rooms are tests/meta/test_rooms.py (checkers in tests/meta/rooms.py).


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


def test_loading_the_plugins_imports_nothing_heavy():
    """Every command loads the identifiers and effects; a plugin module that imports a heavy
    library at its top makes every command pay for it (``scipy.signal`` and the
    ``scipy.stats`` it pulls in cost 1.2 of the 3.3 s an ``identify`` took)."""
    import subprocess
    import sys

    heavy = ("scipy.signal", "scipy.stats", "scipy.optimize", "cvxpy", "pysindy", "fmpy",
             "matplotlib", "sklearn")  # fmt: skip
    code = (
        "import sys, tendonkit as tk; tk.identifiers(); tk.effects(); "
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


#: tendonkit 0.1's public API and commands: the move into rooms kept every one of them.
API_0_1 = [
    "ARX", "Block", "DataError", "Dataset", "Experiment", "FMUError", "Factor", "InputTarget",
    "LinearMPC", "Model", "NoiseCovariance", "NonlinearMPC", "OptionError", "PluginError",
    "Provenance", "SchemaError", "Signal", "SimulationError", "SparseMap", "StateSpace",
    "StepResult", "TendonkitError", "Term", "__version__", "effects", "fit", "fit_table",
    "hookimpl", "identifiers", "identify", "predict", "simulate", "simulate_dataset",
]  # fmt: skip
COMMANDS_0_1 = {
    "identify", "simulate", "compare", "diagnose", "plugins", "demo", "plant", "collect",
    "export", "mpc",
}  # fmt: skip


def test_the_0_1_public_api_and_commands_are_all_still_there():
    assert set(API_0_1) <= set(tendonkit.__all__)
    for name in API_0_1:
        assert getattr(tendonkit, name) is not None
    from tendonkit.cli.app import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert COMMANDS_0_1 <= set(sub.choices)
    assert set(sub.choices) - COMMANDS_0_1 == {"campaign"}  # added since, nothing removed
