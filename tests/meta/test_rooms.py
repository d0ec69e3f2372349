"""The house rules hold on the real tree, and each rule can fail (docs/concepts.md)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
import rooms

ROOT = Path(__file__).resolve().parents[2]


def _report(violations: list[str]) -> str:
    return "\n".join(violations)


def test_rooms_import_only_what_they_may():
    assert rooms.room_violations(ROOT) == [], _report(rooms.room_violations(ROOT))


def test_imports_are_relative_inside_toolkit_and_absolute_across_folders():
    assert rooms.style_violations(ROOT) == [], _report(rooms.style_violations(ROOT))


def test_no_private_name_crosses_a_room():
    assert rooms.private_violations(ROOT) == [], _report(rooms.private_violations(ROOT))


def test_every_function_level_import_defers_something_heavy_and_says_so():
    assert rooms.lazy_violations(ROOT) == [], _report(rooms.lazy_violations(ROOT))


def test_no_import_cycle():
    assert rooms.cycles(ROOT) == []


def test_every_module_is_in_a_room_the_rules_know():
    names = [m for m, _ in rooms.modules(ROOT)]
    assert "tendonkit.diagnose.engine" in names and "tendonkit.robot.kinematics" in names
    assert {rooms.room(m) for m in names} == {
        "core", "diagnose", "mpc", "robot", "cli", "plugins", "fmu"
    }  # fmt: skip


# -- each rule fails on a tree that breaks it ---------------------------------------------------


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for folder in rooms.FOLDERS:
        (tmp_path / folder).mkdir(exist_ok=True)
        (tmp_path / folder / "__init__.py").touch()
    for rel, text in files.items():
        p = tmp_path / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(textwrap.dedent(text))
    return tmp_path


BASE = {
    "toolkit/schema.py": "X = 1\n",
    "toolkit/robot/__init__.py": "",
    "toolkit/robot/kinematics.py": "from ..schema import X\n",
    "toolkit/diagnose/__init__.py": "from .engine import diagnose\n",
    "toolkit/diagnose/engine.py": "def diagnose():\n    return 1\n",
    "toolkit/simulate.py": "def _private():\n    return 1\n",
}


def test_a_clean_fake_tree_passes(tmp_path):
    root = _tree(tmp_path, BASE)
    assert rooms.room_violations(root) == []
    assert rooms.style_violations(root) == []
    assert rooms.private_violations(root) == []
    assert rooms.lazy_violations(root) == []
    assert rooms.cycles(root) == []


@pytest.mark.parametrize(
    ("check", "files", "needle"),
    [
        (
            rooms.room_violations,
            {"toolkit/metrics.py": "from .robot.kinematics import X\n"},
            "core imports tendonkit.robot.kinematics (robot)",
        ),
        (
            rooms.room_violations,
            {"plugins/arx.py": "from tendonkit.diagnose.engine import diagnose\n"},
            "not a room's door",
        ),
        (
            rooms.room_violations,
            {"toolkit/metrics.py": "def f():\n    from tendonkit.plugins import arx  # lazy: x\n"},
            "core imports tendonkit.plugins (plugins)",
        ),
        (
            rooms.room_violations,
            {"toolkit/diagnose/engine.py": "from ..robot import kinematics\n"},
            "diagnose imports tendonkit.robot.kinematics (robot)",
        ),
        (
            rooms.room_violations,
            {"toolkit/cli/__init__.py": "", "toolkit/robot/study.py": "from ..cli import main\n"},
            "robot imports tendonkit.cli (cli)",
        ),
        (
            rooms.room_violations,
            {"toolkit/cli/__init__.py": "", "fmu/build.py": "from tendonkit.cli import main\n"},
            "fmu imports tendonkit.cli (cli)",
        ),
        (
            rooms.room_violations,
            {"plugins/arx.py": "from tendonkit.robot.kinematics import X\n"},
            "plugins imports tendonkit.robot.kinematics (robot)",
        ),
        (
            rooms.style_violations,
            {"toolkit/metrics.py": "from tendonkit.schema import X\n"},
            "absolute import of tendonkit.schema inside toolkit/",
        ),
        (
            rooms.style_violations,
            {"plugins/arx.py": "from ..schema import X\n"},
            "relative import of tendonkit.schema across folders",
        ),
        (
            rooms.private_violations,
            {"toolkit/robot/study.py": "from .._simulate_arx import run\n"},
            "imports private tendonkit._simulate_arx.run",
        ),
        (
            rooms.lazy_violations,
            {"plugins/arx.py": "def f():\n    import numpy as np  # lazy: why not\n"},
            "numpy imported inside a function",
        ),
        (
            rooms.private_violations,
            {"plugins/arx.py": "from tendonkit.simulate import _private\n"},
            "imports private tendonkit.simulate._private",
        ),
        (
            rooms.lazy_violations,
            {"toolkit/metrics.py": "def f():\n    from .schema import X\n    return X\n"},
            "tendonkit.schema imported inside a function",
        ),
        (
            rooms.lazy_violations,
            {"toolkit/metrics.py": "def f():\n    import cvxpy\n    return cvxpy\n"},
            "lazy import of cvxpy without '# lazy:'",
        ),
    ],
)
def test_each_rule_reports_a_tree_that_breaks_it(tmp_path, check, files, needle):
    root = _tree(tmp_path, {**BASE, **files})
    found = check(root)
    assert any(needle in v for v in found), found


def test_what_the_rules_allow_passes(tmp_path):
    files = {
        # plugins may use the rooms' doors and the core
        "plugins/arx.py": "from tendonkit.diagnose import diagnose\nfrom tendonkit.schema import X\n",
        # a type-only import of another room, and a private name inside one's own room
        "toolkit/metrics.py": (
            "from typing import TYPE_CHECKING\n"
            "from ._simulate_arx import run\n"
            "if TYPE_CHECKING:\n"
            "    from .robot.kinematics import X\n"
        ),
        "toolkit/_simulate_arx.py": "def run():\n    return 1\n",
        # robot may import the generic rooms and fmu/ (absolutely: fmu/ is another folder)
        "toolkit/robot/study.py": (
            "from tendonkit.fmu import build\nfrom ..diagnose import diagnose\n"
            "def f():\n    from tendonkit.fmu import build  # lazy: keeps study off fmu/\n"
        ),
        "fmu/build.py": "from tendonkit.robot.kinematics import X\n",
    }
    root = _tree(tmp_path, {**BASE, **files})
    for check in (rooms.room_violations, rooms.style_violations, rooms.private_violations):
        assert check(root) == [], check.__name__
    assert rooms.lazy_violations(root) == []
    assert rooms.cycles(root) == []


def test_a_lazy_import_with_its_reason_passes(tmp_path):
    files = {"toolkit/metrics.py": "def f():\n    import cvxpy  # lazy: heavy (cvxpy)\n"}
    assert rooms.lazy_violations(_tree(tmp_path, {**BASE, **files})) == []


def test_a_cycle_is_reported(tmp_path):
    files = {
        "toolkit/a.py": "from .b import Y\nX = 1\n",
        "toolkit/b.py": "from .a import X\nY = 1\n",
    }
    assert rooms.cycles(_tree(tmp_path, {**BASE, **files})) == [["tendonkit.a", "tendonkit.b"]]
