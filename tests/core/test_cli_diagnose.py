"""The diagnose command: files produced, JSON schema, one clear message for bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

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
        "--versus",
        "pem",
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert d["cause"] == "nonlinear_stiffness"
    # measured against the best linear model too (pem, default options): the cubic beats it
    v = d["versus"]
    assert v["method"] == "pem" and v["fit"] > d["baseline"]["fit"] - 5
    assert (
        v["extended_gain"] == pytest.approx(d["extended"]["fit"] - v["fit"])
        and v["extended_gain"] > 5
    )
    assert set(v["rmse_per_output"]) == {"pos"}
    assert f"against pem (default options, same data): fit {v['fit']:.2f} %" in r.stdout
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
    assert "Against pem (default options" in index


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
        "--versus",
        "nothing",
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    for text in (
        "--versus: unknown identifier 'nothing'",
        "unknown method 'nosuch'",
        "unknown effect 'gremlins'",
        "does not exist",
        "input column 'nope' is not in the file",
    ):
        assert text in r.stderr


def _noisy_oscillator(n, seed):
    """A lightly damped linear oscillator, finely sampled, with 5 % noise on the output."""
    from scipy.signal import butter, lfilter

    rng = np.random.default_rng(seed)
    u = lfilter(*butter(2, 2.0, fs=100.0), rng.standard_normal(n))
    x, v, y = 0.0, 0.0, np.empty(n)
    for k in range(n):  # semi-implicit Euler of x'' = u - 0.6 x' - 40 x, at 100 Hz
        y[k] = x
        v += 0.01 * (u[k] - 0.6 * v - 40.0 * x)
        x += 0.01 * v
    return {"t": 0.01 * np.arange(n), "force": u, "pos": y + 0.05 * y.std() * rng.normal(size=n)}


def test_a_biased_baseline_is_replaced_and_the_note_printed(tmp_path):
    tr = write_csv(tmp_path / "train.csv", _noisy_oscillator(5000, 3))
    va = write_csv(tmp_path / "valid.csv", _noisy_oscillator(5000, 4))
    out = tmp_path / "d.json"
    args = ("diagnose", str(tr), str(va), "--inputs", "force", "--outputs", "pos")
    r = run(*args, "--effects", "gravity,input_delay", "--json", str(out))
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    assert d["baseline"]["method"] == "n4sid" and d["baseline"]["check"]["fallback"]
    assert "diagnosed against n4sid instead" in r.stdout and d["cause"] == "none"
    assert "refined by its simulation error (training fit" in r.stdout
    assert d["baseline"]["check"]["refined_fit"] > d["baseline"]["check"]["reference_fit"]
    r = run(*args, "--effects", "gravity", "--no-fallback", "--json", str(out))
    d = json.loads(out.read_text())
    assert r.returncode == 0 and d["baseline"]["method"] == "arx"
    assert d["baseline"]["check"]["biased"] and "kept (--no-fallback)" in r.stdout


def test_min_gain_and_a_bilinear_baseline_from_the_command_line(tmp_path):
    tr = write_csv(tmp_path / "train.csv", _duffing(3000, 1))
    va = write_csv(tmp_path / "valid.csv", _duffing(1500, 2))
    args = ("diagnose", str(tr), str(va), "--inputs", "force", "--outputs", "pos")
    opts = ("--option", "na=2", "--option", "nb=1", "--option", "bilinear=true")
    out = tmp_path / "d.json"
    r = run(
        *args, *opts, "--effects", "nonlinear_stiffness", "--min-gain", "90", "--json", str(out)
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    # the cubic is found (a large, significant gain) but 90 points is more than it gains
    top = d["findings"][0]
    assert top["cause"] == "nonlinear_stiffness" and 5 < top["gain"] < 90
    assert top["p_adjusted"] < 0.01 and not top["significant"] and d["cause"] == "none"
    assert d["settings"]["min_gain"] == 90.0
    bad = run(*args, "--min-gain", "-1")
    assert bad.returncode == 2 and "min_gain" in bad.stderr and "Traceback" not in bad.stderr


def test_a_diverged_candidate_says_so_in_text_and_strict_json(tmp_path):
    import math

    from tendonkit.cli.diagnose import render_diagnosis
    from tendonkit.diagnose import Finding
    from tendonkit.files import write_json

    f = Finding(
        cause="backlash", effect="backlash", gain=-math.inf, fit={"y": -1e300},
        relative_gain=-4.4e12, p_value=1.0, significant=False, params={}, evidence={},
        description="",
    )  # fmt: skip
    d = f.to_dict()
    assert d["diverged"] is True
    summary = {
        "cause": "none",
        "baseline": {"method": "arx", "fit": 80.0},
        "extended": {},
        "findings": [d],
    }
    assert "diverged" in render_diagnosis(summary) and "-inf" not in render_diagnosis(summary)
    text = write_json(tmp_path / "d.json", summary).read_text()
    assert "Infinity" not in text
    assert json.loads(text)["findings"][0] == {**d, "gain": None, "fit": {"y": -1e300}}


def test_a_baseline_that_does_not_fit_the_validation_data_names_no_cause(tmp_path):
    # Trained on one regime, validated on another: the baseline's validation fit is negative,
    # and its errors must not be read as a cause (the tutorial's -93 % case).
    rng = np.random.default_rng(0)
    n = 3000
    u = rng.normal(size=n)
    y = np.zeros(n)
    for k in range(2, n):
        y[k] = 1.6 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * u[k - 1]
    tr = write_csv(tmp_path / "train.csv", {"t": 0.01 * np.arange(n), "force": u, "pos": y})
    v = np.zeros(n)
    w = np.sign(np.sin(0.01 * np.arange(n))) * 3 + 0.1 * rng.normal(size=n)
    for k in range(2, n):
        v[k] = 0.5 * v[k - 1] + 0.05 * w[k - 1] + 2.0
    va = write_csv(tmp_path / "valid.csv", {"t": 0.01 * np.arange(n), "force": w, "pos": v})
    r = run("diagnose", str(tr), str(va), "--inputs", "force", "--outputs", "pos",
            "--json", str(tmp_path / "d.json"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["baseline"]["fit"] < 0
    assert d["cause"] == "none" and d["baseline"]["unfit"]
    assert "unfit for diagnosis" in r.stdout


def _prbs_plant(n, seed, pole):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 10 + 1), 10)[:n]
    y = np.zeros(n)
    for k in range(1, n):
        y[k] = pole * y[k - 1] + 0.1 * u[k - 1]
    return {"t": 0.01 * np.arange(n), "force": u, "pos": y + 0.01 * y.std() * rng.normal(size=n)}


def test_a_baseline_that_diverges_on_the_validation_data_is_an_error(tmp_path):
    """Trained on an unstable plant (pole 1.02), the baseline's simulation of other data grows
    without bound: it printed 'fit -2583011253065608192.00 %' and gains of 1e18 points (exit 0).
    """
    tr = write_csv(tmp_path / "train.csv", _prbs_plant(400, 1, 1.02))
    va = write_csv(tmp_path / "valid.csv", _prbs_plant(2000, 2, 0.9))
    out = tmp_path / "d.json"
    r = run("diagnose", str(tr), str(va), "--inputs", "force", "--outputs", "pos",
            "--json", str(out))  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "the baseline (arx) diverges on the validation data" in r.stderr
    assert not out.exists()


def test_every_structure_option_given_is_the_baseline_as_given(tmp_path):
    """With na, nb, nk and offset all given the automatic baseline has nothing to select: it
    was a KeyError traceback ('selected'); now the structure is the user's, dead time too."""
    tr = write_csv(tmp_path / "train.csv", _prbs_plant(1500, 1, 0.9))
    va = write_csv(tmp_path / "valid.csv", _prbs_plant(800, 2, 0.9))
    out = tmp_path / "d.json"
    opts = ["--option", "na=2", "--option", "nb=2", "--option", "nk=3", "--option", "offset=false"]
    r = run("diagnose", str(tr), str(va), "--inputs", "force", "--outputs", "pos",
            *opts, "--json", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    d = json.loads(out.read_text())
    choice = d["baseline"]["choice"]
    assert choice["baseline"] == {"na": 2, "nb": [2], "nk": [3], "offset": False}, choice
    assert choice["dead_time_left_to_diagnosis"] == {}
    assert "baseline structure as given" in r.stdout


def test_inputs_the_data_cannot_tell_apart_are_a_warning(tmp_path):
    """An input recorded twice: the diagnosis runs, and says so when it starts (stderr, as
    identify does) and in the JSON."""
    cols = [_prbs_plant(1500, 1, 0.9), _prbs_plant(800, 2, 0.9)]
    for c in cols:
        c["force2"] = c["force"].copy()
    tr = write_csv(tmp_path / "train.csv", cols[0])
    va = write_csv(tmp_path / "valid.csv", cols[1])
    out = tmp_path / "d.json"
    opts = ["--option", "na=2", "--option", "nb=2", "--option", "nk=1", "--option", "offset=false"]
    r = run("diagnose", str(tr), str(va), "--inputs", "force,force2", "--outputs", "pos",
            *opts, "--json", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    said = "tendonkit: warning: Training data: the inputs force, force2 are linearly dependent"
    assert r.stderr.count(said) == 1, r.stderr
    assert "(force2 = 1·force + 0)" in json.loads(out.read_text())["warnings"][0]
