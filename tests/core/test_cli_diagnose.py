"""The diagnose command: files produced, JSON schema, one clear message for bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from tendonkit.dataset import write_csv


def _duffing(n, seed):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=n)
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.6 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * u[k - 1] - 2.0 * y[k - 1] ** 3
    y += 0.01 * y.std() * rng.normal(size=n)
    return {"t": 0.01 * np.arange(n), "force": u, "pos": y}


def run(*args):
    return subprocess.run(
        [sys.executable, "-m", "tendonkit.cli", *args], capture_output=True, text=True
    )


def test_diagnose_writes_json_model_and_report(tmp_path):
    tr = write_csv(tmp_path / "train.csv", _duffing(3000, 1))
    va = write_csv(tmp_path / "valid.csv", _duffing(1500, 2))
    out = tmp_path / "out" / "d.json"
    r = run(
        "diagnose",
        str(tr),
        str(va),
        "--inputs",
        "force",
        "--outputs",
        "pos",
        "--option",
        "na=2",
        "--option",
        "nb=1",
        "--json",
        str(out),
        "--report",
        str(tmp_path / "out"),
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert d["cause"] == "nonlinear_stiffness"
    assert d["extended"]["fit"] > d["baseline"]["fit"] + 10
    for key in ("method", "fit"):
        assert key in d["baseline"]
    ranked = [f["gain"] for f in d["findings"]]
    assert all(set(f) >= {"cause", "gain", "params", "evidence"} for f in d["findings"])
    assert d["findings"][0]["cause"] == "nonlinear_stiffness" and ranked[0] == max(ranked)
    model = json.loads(open(d["extended"]["model"]).read())
    assert model["representation"]["terms"]  # the extension is in the saved model
    index = (tmp_path / "out" / "index.html").read_text()
    assert "nonlinear_stiffness" in index and index.count("<img") >= 3


def test_diagnose_bad_input_is_one_message(tmp_path):
    tr = write_csv(tmp_path / "train.csv", _duffing(300, 1))
    r = run(
        "diagnose",
        str(tr),
        str(tmp_path / "missing.csv"),
        "--inputs",
        "force,nope",
        "--outputs",
        "pos",
        "--method",
        "nosuch",
        "--effects",
        "gremlins",
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    for text in (
        "unknown method 'nosuch'",
        "unknown effect 'gremlins'",
        "does not exist",
        "input column 'nope' is not in the file",
    ):
        assert text in r.stderr
