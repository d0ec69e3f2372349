"""Every command of docs/tutorial.md runs as written (the tutorial cannot rot)."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.first]

TUTORIAL = Path(__file__).resolve().parents[2] / "docs" / "tutorial.md"


def tutorial_commands() -> list[list[str]]:
    """The ``tendonkit ...`` lines of the tutorial's fenced code blocks, continuations joined."""
    commands, block, inside = [], [], False
    for line in TUTORIAL.read_text().splitlines():
        if line.startswith("```"):
            inside = not inside and line.strip() == "```"
            continue
        if inside:
            block.append(line)
            if not line.rstrip().endswith("\\"):
                text = " ".join(part.rstrip(" \\") for part in block).strip()
                block = []
                if text.startswith("tendonkit "):
                    commands.append(shlex.split(text))
    return commands


def test_the_tutorial_has_the_whole_path():
    verbs = [c[1] for c in tutorial_commands()]
    for verb in ("collect", "identify", "compare", "diagnose", "export", "plant", "mpc"):
        assert verb in verbs


def test_every_tutorial_command_runs(tmp_path):
    env = {**os.environ, "TENDONKIT_CACHE": str(tmp_path / "cache")}  # built plants stay here
    for cmd in tutorial_commands():
        r = subprocess.run(
            [sys.executable, "-m", "tendonkit.cli", *cmd[1:]],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
            env=env,
        )
        assert r.returncode == 0, f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}"
    for produced in ("n4sid.json", "table.json", "diagnosis.json", "robot.fmu", "mpc.json"):
        assert (tmp_path / produced).exists(), produced
    assert list((tmp_path / "figures").glob("*.png"))
