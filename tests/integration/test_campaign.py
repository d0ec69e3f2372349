"""Co-simulation campaigns (issue 19): the same table on every engine, workers that die, resume.

A campaign here is small (3-second petals, a few draws) so that what is tested is the engine and
the bookkeeping; the 200-run campaign of 60-second petals is benchmarks/bench_campaign.py.
"""

from __future__ import annotations

import json
import textwrap

import pytest

from tendonkit.cli import main
from tendonkit.errors import OptionError
from tendonkit.mpc.examples import two_mode_model
from tendonkit.robot.campaign import DETERMINISTIC, load_spec, rerun, run_campaign, spec_from_dict

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("campaign")]

# A controller of the user's: the kinematic open loop, but it kills its own worker process the
# first time it meets the plant draw named in the marker folder (a crash in native code).
USER_CONTROLLER = """
import os
from pathlib import Path

import numpy as np

from tendonkit.robot.cosim import PRETENSION
from tendonkit.robot.kinematics import commanded_tensions


class Kinematic:
    horizon = 1

    def __init__(self, marker="", die_on_q1=None, always=False):
        self.marker = Path(marker) if marker else None
        self.die_on_q1 = die_on_q1
        self.always = always

    def reset(self, u0=None, y0=None):
        self.first = True

    def step(self, y, r_future):
        if self.first and self.marker is not None and self.die_on_q1 is not None:
            self.first = False
            if self.always:
                os._exit(9)
            if abs(float(y[0]) - self.die_on_q1) < 1e-12 and not any(self.marker.glob("died*")):
                (self.marker / "died").touch()
                os._exit(9)
        return commanded_tensions(np.asarray(r_future[:1]), PRETENSION)[0]
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("campaign")
    two_mode_model().save(d / "linear.json")
    (d / "usercontrol.py").write_text(USER_CONTROLLER)
    return d


def user_controller(**options):
    """The user's controller of USER_CONTROLLER, as a [[controllers]] table."""
    table = {"name": "user", "kind": "python", "class": "usercontrol:Kinematic", "path": "."}
    return {**table, **({"options": options} if options else {})}


def spec_dict(**over):
    spec = {
        "campaign": {"name": "small", "seed": 3, "draws": 3},
        "plant": {
            "effects": ["N"],
            "vary": {
                "friction_mu_k": "spec",
                "delay_s": {"values": [0.0, 0.06]},
            },
        },
        "controllers": [
            {"name": "linear MPC", "model": "linear.json", "horizon": 10},
            {"name": "open loop", "kind": "open_loop"},
        ],
        "references": [{"kind": "petal", "duration": 3.0}],
        "criteria": {"require": ["rms_error_true_mrad <= 60", "fallbacks == 0"]},
    }
    for k, v in over.items():
        spec[k] = {**spec.get(k, {}), **v} if isinstance(v, dict) else v
    return spec


def test_local_cluster_and_process_pool_give_the_serial_table(folder, tmp_path):
    spec = spec_from_dict(spec_dict(), base_dir=folder)
    serial = run_campaign(spec, tmp_path / "serial", jobs=1, report=False)
    pool = run_campaign(spec, tmp_path / "pool", jobs=2, report=False)
    dask = run_campaign(spec, tmp_path / "dask", jobs=2, scheduler="local", report=False)
    assert len(serial.rows) == 6
    assert serial.table(deterministic=True) == pool.table(deterministic=True)
    assert serial.table(deterministic=True) == dask.table(deterministic=True)
    assert dask.summary["timing"]["engine"] == "dask" and dask.summary["timing"]["workers"] == 2
    assert len({r["worker"] for r in dask.rows}) == 2  # both workers ran
    # the draws are real: parameters inside the spec's range, delays from the list, and the
    # controllers differ on the same plant
    assert all(
        0.05 <= r["friction_mu_k"] <= 0.3 and r["delay_s"] in (0.0, 0.06) for r in serial.rows
    )
    lin = [r["rms_error_true_mrad"] for r in serial.rows if r["controller"] == "linear MPC"]
    ol = [r["rms_error_true_mrad"] for r in serial.rows if r["controller"] == "open loop"]
    assert lin != ol and all(x > 0 for x in lin + ol)
    assert (tmp_path / "serial" / "runs.csv").read_text().count("\n") == 7


def test_a_killed_worker_loses_only_its_run_on_both_engines(folder, tmp_path):
    # run 2 (draw 1, the user's controller) kills its worker on its first attempt
    base = spec_dict(controllers=[])
    serial_spec = spec_from_dict({**base, "controllers": [user_controller()]}, base_dir=folder)
    reference = run_campaign(serial_spec, tmp_path / "ref", jobs=1, report=False)
    q1_at_start = rerun(reference, 1).y[0, 0]  # the measured q1 the controller sees first in run 1
    # dask with one worker: the worker that dies is the only one holding the campaign's data,
    # which must reach its restarted successor (a worker plugin, not scattered data)
    for engine, kwargs in (("pool", {"jobs": 2}), ("dask", {"jobs": 1, "scheduler": "local"})):
        marker = tmp_path / f"marker-{engine}"
        marker.mkdir()
        killer = user_controller(marker=str(marker), die_on_q1=float(q1_at_start))
        spec = spec_from_dict({**base, "controllers": [killer]}, base_dir=folder)
        res = run_campaign(spec, tmp_path / engine, report=False, **kwargs)
        assert (marker / "died").exists(), engine  # a worker really died
        assert [r["attempts"] for r in res.rows] == [1, 2, 1], engine
        assert res.summary["retried"] == [{"run": 1, "attempts": 2}]
        assert all(r["status"] == "ok" for r in res.rows)
        assert res.table(deterministic=True) == reference.table(deterministic=True), engine


def test_an_interrupted_campaign_resumes_from_the_rows_written(folder, tmp_path):
    spec = spec_from_dict(spec_dict(), base_dir=folder)
    full = run_campaign(spec, tmp_path / "full", jobs=1, report=False)
    out = tmp_path / "cut"
    run_campaign(spec, out, jobs=1, report=False)
    lines = (out / "runs.jsonl").read_text().splitlines()
    # the interruption: 2 rows kept, the third cut half-way through its line
    (out / "runs.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:17])
    resumed = run_campaign(spec, out, jobs=1, report=False)
    assert resumed.resumed == 2 and resumed.summary["timing"]["runs_now"] == 4
    assert resumed.table(deterministic=True) == full.table(deterministic=True)
    # another campaign in the same folder is refused, nothing is lost; --fresh sets rows aside
    other = spec_from_dict(spec_dict(campaign={"seed": 4}), base_dir=folder)
    with pytest.raises(OptionError, match="holds the rows of another campaign"):
        run_campaign(other, out, jobs=1, report=False)
    assert len((out / "runs.jsonl").read_text().splitlines()) == 6
    run_campaign(other, out, jobs=1, report=False, fresh=True)
    assert len(list(out.glob("runs-*.jsonl.old"))) == 1


def test_the_cli_writes_table_summary_and_report_and_exits_by_the_pass_rate(
    folder, tmp_path, capsys
):
    spec = folder / "cli.toml"
    spec.write_text(
        textwrap.dedent(
            """
            [campaign]
            name = "cli"
            seed = 1
            draws = 2

            [plant]
            effects = ["N"]
            [plant.vary]
            forcelag_tau = { range = [0.05, 0.5] }
            forcelag_on = { values = [true] }

            [[controllers]]
            name = "linear MPC"
            model = "linear.json"
            horizon = 10

            [[references]]
            kind = "petal"
            duration = 3

            [criteria]
            require = ["rms_error_true_mrad <= 0.001"]
            min_pass_rate = 0.5
            """
        )
    )
    out = tmp_path / "out"
    code = main(
        [
            "campaign",
            str(spec),
            "--out",
            str(out),
            "--jobs",
            "1",
            "--json",
            str(tmp_path / "s.json"),
        ]
    )
    text = capsys.readouterr().out
    assert code == 1  # nothing tracks to a micro-radian: the pass rate 0 % is below 50 %
    assert "campaign cli: 0 of 2 runs passed" in text and "worst: run" in text
    for name in (
        "runs.csv",
        "summary.json",
        "index.html",
        "figures/metric_vs_parameters.png",
        "figures/distributions.png",
        "figures/worst_0_tracking.png",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["worst"][0]["parameters"]["forcelag_tau"] > 0.05
    assert "rms_error_true_mrad <= 0.001" in summary["worst"][0]["failed"]
    html = (out / "index.html").read_text()
    assert "Worst cases" in html and "metric_vs_parameters.png" in html


def test_a_bad_spec_lists_every_problem(folder, tmp_path, capsys):
    bad = folder / "bad.toml"
    bad.write_text(
        textwrap.dedent(
            """
            [campaign]
            draws = 0
            colour = "red"
            [plant.vary]
            friction_mu_k = { range = [0.01, 0.9] }
            wobble = "spec"
            [[controllers]]
            model = "missing.json"
            [[references]]
            kind = "spiral"
            [criteria]
            require = ["rms_error_true_mrad <= 25", "happiness >= 1", "fallbacks is 0"]
            rank_by = []
            """
        )
    )
    code = main(["campaign", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    for needle in (
        "draws must be a whole number",
        "unknown key(s) colour",
        "leaves the plant's valid range [0.05, 0.3]",
        "wobble: not a plant parameter",
        "missing.json",
        "kind must be one of petal, circle, step",
        "unknown metric 'happiness'",
        "'fallbacks is 0' is not 'METRIC OP NUMBER'",
        "rank_by must be a metric",
    ):
        assert needle in err, needle
    # values of the wrong type, and a scheduler that is no address, are problems too
    typed = folder / "typed.toml"
    typed.write_text(
        '[plant]\npreset = []\n[[controllers]]\nkind = "open_loop"\nhorizon = 3\n'
        '[[references]]\nduration = "60"\n'
    )
    code = main(["campaign", str(typed), "--out", str(tmp_path / "o"), "--scheduler", "lcoal"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    for needle in (
        "preset must be one of nominal, paper_like",
        "the open loop takes no horizon",
        "duration must be a number of seconds > 0",
        "neither 'local' nor an address",
    ):
        assert needle in err, needle
    assert not (tmp_path / "o").exists()
    with pytest.raises(OptionError, match="not valid TOML"):
        (folder / "broken.toml").write_text("[campaign\n")
        load_spec(folder / "broken.toml")


def test_a_folder_in_use_is_refused_and_lost_rows_run_again_on_resume(folder, tmp_path):
    import fcntl

    spec = spec_from_dict(spec_dict(campaign={"draws": 1}), base_dir=folder)
    out = tmp_path / "busy"
    out.mkdir()
    with (out / ".lock").open("a") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX)  # another campaign is running here
        with pytest.raises(OptionError, match="another campaign is writing"):
            run_campaign(spec, out, jobs=1, report=False)
    assert not (out / "runs.jsonl").exists()  # refused before touching anything
    first = run_campaign(spec, out, jobs=1, report=False)
    lines = (out / "runs.jsonl").read_text().splitlines()
    lost = json.loads(lines[1])
    lost.update(value=None, error="WorkerDied: the worker running it died 3 times", attempts=3)
    (out / "runs.jsonl").write_text(lines[0] + "\n" + json.dumps(lost) + "\n")
    again = run_campaign(spec, out, jobs=1, report=False)
    assert again.resumed == 1 and again.summary["timing"]["runs_now"] == 1
    assert again.table(deterministic=True) == first.table(deterministic=True)


def test_a_run_whose_worker_always_dies_is_reported_on_dask(folder, tmp_path):
    marker = tmp_path / "m"
    marker.mkdir()
    dies = user_controller(marker=str(marker), die_on_q1=0.0, always=True)
    spec = spec_from_dict(
        {**spec_dict(campaign={"draws": 2}), "controllers": [dies]}, base_dir=folder
    )
    res = run_campaign(spec, tmp_path / "out", jobs=2, scheduler="local", report=False)
    died = [r for r in res.rows if r["status"] == "error"]
    assert len(died) == 2 and all(r["error"].startswith("WorkerDied") for r in died)
    assert all(r["attempts"] == 3 for r in died)  # the first start and 2 retries
    assert res.summary["pass_rate"] == 0.0


def test_draws_depend_on_the_seed_and_their_number_only(folder):
    small = spec_from_dict(spec_dict(), base_dir=folder)
    large = spec_from_dict(spec_dict(campaign={"draws": 50}), base_dir=folder)
    assert [small.draw(d) for d in range(3)] == [large.draw(d) for d in range(3)]
    assert small.noise_seed(1, 0) == large.noise_seed(1, 0) != large.noise_seed(2, 0)
    other = spec_from_dict(spec_dict(campaign={"seed": 4}), base_dir=folder)
    assert other.draw(0) != small.draw(0)
    g = spec_dict(
        plant={
            "vary": {
                "delay_s": {"range": [0.0, 0.1], "points": 3},
                "mount": {"values": ["none", "horiz_tilt"]},
            }
        }
    )
    g["campaign"] = {"name": "grid", "sampling": "grid"}
    grid = spec_from_dict(g, base_dir=folder)
    assert grid.n_draws == 6 and grid.n_runs == 12
    assert {(grid.draw(d)["delay_s"], grid.draw(d)["mount"]) for d in range(6)} == {
        (x, m) for x in (0.0, 0.05, 0.1) for m in ("none", "horiz_tilt")
    }
    assert set(DETERMINISTIC) >= {"run", "rms_error_true_mrad", "fallbacks", "status"}
    assert "wall_s" not in DETERMINISTIC


def test_a_pool_worker_killed_from_outside_mid_campaign_loses_only_its_run(folder, tmp_path):
    """SIGKILL to a busy pool worker while the campaign runs: it completes, nothing is lost."""
    import multiprocessing
    import os
    import signal
    import threading
    import time

    spec = spec_from_dict(
        spec_dict(campaign={"draws": 4}, references=[{"kind": "petal", "duration": 8.0}]),
        base_dir=folder,
    )
    reference = run_campaign(spec, tmp_path / "serial", jobs=1, report=False)
    out = tmp_path / "pool"
    result: dict = {}
    thread = threading.Thread(
        target=lambda: result.update(r=run_campaign(spec, out, jobs=2, report=False))
    )
    thread.start()
    journal = out / "runs.jsonl"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (journal.exists() and journal.read_text()):
        time.sleep(0.02)
    victims = [p for p in multiprocessing.active_children() if p.is_alive()]
    assert victims, "no pool worker to kill"
    os.kill(victims[0].pid, signal.SIGKILL)
    thread.join(timeout=300)
    res = result["r"]
    assert all(r["status"] == "ok" for r in res.rows) and len(res.rows) == 8
    assert not victims[0].is_alive()
    # the run it held (if it was not between two runs) started again, on whichever worker
    # was free first; nothing else was touched
    assert sum(r["attempts"] > 1 for r in res.rows) <= 1
    victim = f":{victims[0].pid}"
    assert sum(r["worker"].endswith(victim) for r in res.rows) <= 1  # it finished at most one
    assert res.table(deterministic=True) == reference.table(deterministic=True)


def test_a_spec_with_mistakes_runs_none_of_its_code_and_json_never_replaces_an_input(
    folder, tmp_path, capsys
):
    """The user's module is imported only once everything else in the spec is valid (docs:
    reading a spec executes nothing), and ``--json`` may not name the spec or a model it reads
    (the summary would replace it)."""
    (folder / "marks.py").write_text(
        "from pathlib import Path\n"
        f"Path({str(tmp_path / 'IMPORTED')!r}).touch()\n"
        "class C:\n    def step(self, y, r):\n        return y\n"
    )
    bad = folder / "marks.toml"
    bad.write_text(
        '[campaign]\ndraws = 0\n[[controllers]]\nname = "mine"\nkind = "python"\n'
        'class = "marks:C"\npath = "."\n'
    )
    code = main(["campaign", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "draws must be a whole number" in err
    assert not (tmp_path / "IMPORTED").exists()
    # a plant the spec cannot build (checked after the rest of the spec), and a valid spec with
    # bad command-line arguments: neither runs the module either
    user = '[[controllers]]\nname = "mine"\nkind = "python"\nclass = "marks:C"\npath = "."\n'
    bad.write_text('[plant]\neffects = ["no_such_parameter=1"]\n' + user)
    assert main(["campaign", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "no_such_parameter" in capsys.readouterr().err
    bad.write_text(user)
    assert main(["campaign", str(bad), "--out", str(bad), "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err
    assert not (tmp_path / "IMPORTED").exists()
    # valid otherwise: the class is imported and checked, and its problem is reported
    bad.write_text(
        '[[controllers]]\nname = "mine"\nkind = "python"\nclass = "marks:C"\npath = "."\n'
        "options = { gain = 2 }\n"
    )
    code = main(["campaign", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "options do not fit marks:C" in err
    assert (tmp_path / "IMPORTED").exists()
    spec = folder / "tiny.toml"
    spec.write_text(
        '[campaign]\nname = "tiny"\n[[controllers]]\nname = "lin"\nmodel = "linear.json"\n'
        '[[references]]\nkind = "step"\nduration = 0.3\n'
    )
    before = {p: p.read_bytes() for p in (spec, folder / "linear.json")}
    for target in (spec, folder / "linear.json"):
        code = main(["campaign", str(spec), "--out", str(tmp_path / "t"), "--json", str(target)])
        err = capsys.readouterr().err
        assert code == 2 and "is also an input; refusing to overwrite it" in err, err
    assert {p: p.read_bytes() for p in before} == before
    code = main(
        ["campaign", str(spec), "--out", str(tmp_path / "t"), "--json", str(tmp_path / "t")]
    )
    assert code == 2 and "--json and --out name the same path" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()
