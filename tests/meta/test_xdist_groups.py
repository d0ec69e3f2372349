"""``make test`` runs ``--dist loadgroup``: an ``xdist_group`` must keep its tests on one worker.

The suite's session fixtures (the demo run, built FMUs) are shared within a group; when the
groups are silently ignored, each worker builds them again or waits for another's lock.  That
happened with pytest 9.2 and pytest-xdist 3.8 (pytest-dev/pytest-xdist#1386), which is why
pyproject.toml keeps pytest below 9.2; this test fails the day an upgrade breaks it again.
"""

from __future__ import annotations

import re
import subprocess
import sys


def test_a_group_runs_on_one_worker(tmp_path):
    (tmp_path / "test_grouped.py").write_text(
        "import pytest\n"
        "pytestmark = pytest.mark.xdist_group('g')\n"
        + "".join(f"def test_{i}():\n    pass\n" for i in range(6))
    )
    (tmp_path / "test_free.py").write_text(
        "".join(f"def test_{i}():\n    pass\n" for i in range(6))
    )
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-v",
         "-p", "no:cacheprovider", "-p", "no:tendonkit", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    workers = set(re.findall(r"\[(gw\d+)\].*PASSED.*test_grouped\.py", r.stdout))
    assert len(workers) == 1, r.stdout[-3000:]
    assert len(re.findall(r"PASSED.*test_grouped\.py", r.stdout)) == 6
