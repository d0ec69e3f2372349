"""The pytest plugin (issue 19): the guide's example file runs, passes, and its checks can fail."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "pytest-plugin.md"

pytestmark = [pytest.mark.slow]


def example() -> str:
    blocks = re.findall(r"```python\n(.*?)```", GUIDE.read_text(), flags=re.S)
    [block] = [b for b in blocks if "def test_" in b]
    return block


def run_pytest(folder: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PYTEST_XDIST_WORKER", None)
    env.pop("PYTEST_ADDOPTS", None)
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist", *args],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_the_guides_example_file_passes_with_the_installed_plugin(tmp_path):
    (tmp_path / "test_mpc_robustness.py").write_text(example())
    proc = run_pytest(tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "7 passed" in proc.stdout
    # the draws are parametrised as their own test ids
    ids = run_pytest(tmp_path, "--collect-only")
    assert ids.stdout.count("test_mpc_holds_on_friction[") == 3
    assert "delay_s=0.06" in ids.stdout


def test_a_failing_check_names_every_unmet_criterion_and_the_plant(cosim):
    # the plugin's fixtures are installed here too: this test uses ``cosim`` itself
    from tendonkit.mpc.examples import two_mode_model

    run = cosim(two_mode_model(), plant={"friction_mu_k": 0.25}, duration=3.0)
    with pytest.raises(pytest.fail.Exception) as failed:
        run.check(rms_error_true_mrad=0.001, ee_error_true_cm="< 0.0001", fallbacks="== 0")
    out = str(failed.value)
    assert "rms_error_true_mrad <= 0.001 (got" in out and "ee_error_true_cm < 0.0001 (got" in out
    assert "fallbacks ==" not in out  # the criterion that held is not listed
    assert "friction_mu_k=0.25" in out
    run.check(fallbacks="== 0", bound_violations=0)  # what holds passes
