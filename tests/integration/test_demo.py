"""`tendonkit demo --quick` end to end: files produced, tables parse and agree with the report."""

from __future__ import annotations

import fcntl
import json
import re
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("test_demo")]


@pytest.fixture(scope="session")
def demo(tmp_path_factory, testrun_uid):
    """One demo run per test session, shared by every xdist worker (a file lock, one writer).

    ``--dist loadgroup`` does not always keep this module's tests on one worker, so each
    worker would otherwise run the demo (20 s) itself.
    """
    root = tmp_path_factory.getbasetemp().parent  # the same folder for every worker
    out = root / f"demo-{testrun_uid}"
    with open(root / f"demo-{testrun_uid}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = root / f"demo-{testrun_uid}.stdout"
        if not done.exists():
            out.mkdir(exist_ok=True)
            r = subprocess.run(
                [sys.executable, "-m", "tendonkit.cli", "demo", "--quick", "--out", str(out)],
                capture_output=True,
                text=True,
                timeout=600,
            )
            assert r.returncode == 0, r.stderr[-3000:]
            done.write_text(r.stdout)
    return out, done.read_text()


def test_files_are_produced(demo):
    out, _ = demo
    for name in (
        "index.html",
        "summary.json",
        "model.fmu",
        "plant_paper_like.fmu",
        "n4sid.json",
        "arx.json",
        "sindyc.json",
        "diagnose/index.html",
        "diagnose/extended_model.json",
        "diagnose_tensions/index.html",
        "diagnose_tensions/extended_model.json",
    ):
        assert (out / name).exists(), name
    pngs = list((out / "figures").glob("*.png"))
    assert len(pngs) >= 8  # Fig. 2 (2), Fig. 3 and 4 per method (6)
    html = (out / "index.html").read_text()
    for png in pngs:
        assert png.name in html or "mpc" in png.name


def test_printed_table_parses_and_agrees_with_summary_and_report(demo):
    out, stdout = demo
    summary = json.loads((out / "summary.json").read_text())
    rows = {r["model"]: r for r in summary["table_1"]["models"]}
    html = (out / "index.html").read_text()
    for method, paper in (("n4sid", 39.12), ("arx", 44.90), ("sindyc", 67.74)):
        m = re.search(rf"^{method}\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)$", stdout, re.M)
        assert m, f"no Table I row for {method} in the printed output"
        q1, q2, mean, printed_paper = map(float, m.groups())
        assert printed_paper == paper
        assert q1 == pytest.approx(rows[method]["fit"]["q1"], abs=0.006)
        assert q2 == pytest.approx(rows[method]["fit"]["q2"], abs=0.006)
        assert mean == pytest.approx(rows[method]["mean_fit"], abs=0.006)
        assert f"<td>{mean:.2f}</td>" in html  # the report shows the same number
    assert summary["export"]["problems"] == []
    assert summary["export"]["max_difference"] < 1e-9
    for name, res in summary["mpc"]["results"].items():
        assert res["input_bound_violations"] == 0, name
    from tendonkit.registry import CAUSES

    assert summary["diagnosis"]["cause"] in CAUSES
    assert summary["diagnosis_tensions"]["cause"] in CAUSES


def test_the_diagnosis_names_what_the_plant_hides_and_the_mpc_uses_it(demo):
    """The paper-like plant hides a force-controller lag (with the carriage's rate limit) in
    front of the tendons and the tendons' friction behind the measured forces: the diagnosis
    of the commanded path names the lag, that of the tensions a friction-like cause (friction,
    or the play it looks like quasi-statically), each with a gain; the linear MPC then runs on
    the N4SID model as the diagnosis extended it, beside the unextended one."""
    out, stdout = demo
    summary = json.loads((out / "summary.json").read_text())
    commanded, tensions = summary["diagnosis"], summary["diagnosis_tensions"]
    assert "actuator_lag" in commanded["causes"]
    assert {"coulomb_friction", "backlash", "hysteresis"} & set(tensions["causes"])
    for d in (commanded, tensions):
        steps = [st for st in d["sequence"] if st["cause"] != "none"]
        assert steps and all(st["gain"] > 0 for st in steps)
    rows = summary["mpc"]["results"]
    extended = [n for n in rows if n.startswith("linear MPC (N4SID + ")]
    assert extended == ["linear MPC (N4SID + " + ", ".join(commanded["causes"]) + ")"]
    assert rows[extended[0]]["input_bound_violations"] == 0
    assert summary["mpc"]["extended"].startswith(extended[0])
    assert "Diagnosis of the linear MPC's model" in stdout
    assert "Diagnosis of the best model on the measured tensions" in stdout
    assert extended[0] in (out / "index.html").read_text()


def test_what_a_newcomer_reads_is_honest(demo):
    out, stdout = demo
    text = (out / "summary.json").read_text()
    # strict JSON: a diverged candidate is null, never -Infinity (JavaScript refuses it)
    assert "Infinity" not in text and "NaN" not in text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    summary = json.loads(text)
    extended = summary["diagnosis"]["cause"] != "none" if "diagnosis" in summary else None
    if extended is False:
        assert "export the best (extended) model" not in stdout
    html = (out / "index.html").read_text()
    assert ">nan<" not in html  # the open-loop row says it has no solver
    report = (out / "diagnose" / "index.html").read_text()
    sources = re.findall(r"<img src='([^']*)'", report)
    assert sources and not any("_none" in s for s in sources), sources
    captions = re.findall(r"<img src='[^']*' alt='([^']*)'>", report)
    assert len(captions) == len(set(captions)), "two figures share one caption"


def test_the_demo_campaign_reports_pass_rate_and_worst_plant(demo):
    out, stdout = demo
    camp = json.loads((out / "summary.json").read_text())["campaign"]
    assert camp["runs"] == 24 and 0 <= camp["passed"] <= 24
    rows = (out / "campaign" / "runs.csv").read_text().splitlines()
    assert len(rows) == 25 and rows[0].startswith("run,draw,repeat,controller")
    passed = sum(line.split(",")[rows[0].split(",").index("passed")] == "True" for line in rows[1:])
    assert passed == camp["passed"]
    worst = camp["worst"]
    assert set(worst["parameters"]) == {"friction_mu_k", "forcelag_tau", "delay_s"}
    assert worst["rms_error_true_mrad"] == pytest.approx(camp["distribution"]["max"])
    m = re.search(r"the linear MPC passed (\d+) of 24", stdout)
    assert m and int(m.group(1)) == camp["passed"]
    assert f"run {worst['run']}," in stdout
    html = (out / "index.html").read_text()
    assert (
        "Campaign: the linear MPC across plant draws" in html and "metric_vs_parameters.png" in html
    )
    assert (out / "campaign" / "index.html").is_file()
