"""The wheel holds every module of the tree and every subpackage imports from it.

A subpackage missing from ``[tool.setuptools] packages`` in pyproject.toml breaks only the wheel
(the editable install maps the folders), so the test builds the wheel, installs it into a fresh
folder and imports every module from there, in an interpreter that cannot see the checkout.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
import rooms

# one worker runs this module (make test: --dist loadgroup), and its session-scoped fixtures
# are built once there (module scope would rebuild them when other tests interleave)
pytestmark = pytest.mark.xdist_group("test_wheel")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(out), str(ROOT)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    (path,) = out.glob("tendonkit-*.whl")
    return path


def test_the_wheel_holds_every_module_of_the_tree(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = {
        "/".join(m.split(".")) + ("/__init__.py" if p.name == "__init__.py" else ".py")
        for m, p in rooms.modules(ROOT)
    }
    missing = sorted(expected - names)
    assert not missing, f"not in the wheel (add the package to pyproject.toml): {missing}"
    assert "tendonkit/py.typed" in names


def test_every_module_imports_from_the_installed_wheel(wheel, tmp_path):
    site = tmp_path / "site"
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site),
         str(wheel)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    deps = sysconfig.get_paths()["purelib"]  # numpy & co.; no .pth runs under -S
    code = (
        "import importlib, pkgutil, tendonkit\n"
        "print(tendonkit.__file__)\n"
        "for m in pkgutil.walk_packages(tendonkit.__path__, 'tendonkit.'):\n"
        "    if not m.name.endswith('__main__'):\n"
        "        importlib.import_module(m.name)\n"
        "print('imported', len(list(pkgutil.walk_packages(tendonkit.__path__, 'tendonkit.'))))\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), deps])}
    r = subprocess.run(
        [sys._base_executable, "-S", "-c", code],  # type: ignore[attr-defined]
        capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    first, last = r.stdout.splitlines()[0], r.stdout.splitlines()[-1]
    assert first.startswith(str(site)), first
    assert int(last.split()[1]) == len(list(rooms.modules(ROOT))) - 1  # all but the root
