"""The command line: identify -> simulate -> compare, and one clear message per user error."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.dataset import Dataset


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tendonkit.cli", *args], capture_output=True, text=True
    )


def test_identify_simulate_compare_round_trip(tmp_path, csv_file, small_data, capsys):
    data = csv_file()
    model = tmp_path / "m.json"
    assert (
        main(
            [
                "identify",
                str(data),
                "--method",
                "arx",
                "--inputs",
                "u1,u2",
                "--outputs",
                "y1,y2",
                "--option",
                "na=4",
                "--option",
                "nb=4",
                "-o",
                str(model),
            ]
        )
        == 0
    )
    assert json.loads(model.read_text())["representation"]["kind"] == "arx"
    pred = tmp_path / "pred.csv"
    assert main(["simulate", str(model), str(data), "-o", str(pred)]) == 0
    header = pred.read_text().splitlines()[0]
    assert header == "t,y1,y2"
    sim = Dataset.from_csv(pred, [], ["y1", "y2"], require_outputs=True)
    assert sim.n_samples == Dataset.from_csv(data, ["u1"], ["y1"]).n_samples
    out = tmp_path / "cmp.json"
    assert main(["compare", str(data), str(model), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["models"][0]["mean_fit"] > 90
    printed = capsys.readouterr().out
    assert "mean [%]" in printed and f"{res['models'][0]['mean_fit']:.2f}" in printed


def test_errors_are_listed_once_with_exit_2_and_no_traceback(tmp_path, csv_file):
    data = csv_file()
    r = run(
        "identify",
        str(data),
        "--method",
        "nosuch",
        "--inputs",
        "u1,F9",
        "--outputs",
        "y1",
        "--option",
        "garbage",
        "-o",
        str(tmp_path / "missing" / "m.json"),
    )
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    for expected in (
        "unknown method 'nosuch'",
        "'garbage' is not of the form KEY=VALUE",
        "folder of output",
        "input column 'F9' is not in the file",
    ):
        assert expected in r.stderr
    assert r.stderr.count("tendonkit: error:") == 1


def test_bad_option_values_are_reported(tmp_path, csv_file):
    r = run(
        "identify",
        str(csv_file()),
        "--method",
        "arx",
        "--inputs",
        "u1",
        "--outputs",
        "y1",
        "--option",
        "na=-1",
        "--option",
        "nb=x",
        "--option",
        "bogus=1",
        "-o",
        str(tmp_path / "m.json"),
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "unknown option 'bogus'" in r.stderr
    # the type in words, not Python's (it said "is not a valid Union")
    assert "nb='x' is not a valid whole number, tuple of whole numbers or 'auto'." in r.stderr


def test_empty_column_names_are_refused(tmp_path, csv_file):
    """``--inputs ""`` built a model with no inputs (1.5 % fit) and ``u1,,u2`` dropped the gap."""
    out = tmp_path / "m.json"
    r = run("identify", str(csv_file()), "--inputs", "", "--outputs", "y1,", "-o", str(out))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "--inputs names no column." in r.stderr
    assert "--outputs 'y1,' has an empty name" in r.stderr
    r = run("identify", str(csv_file()), "--inputs", "u1,,u2", "--outputs", "y1", "-o", str(out))
    assert r.returncode == 2 and "--inputs 'u1,,u2' has an empty name" in r.stderr
    assert not out.exists()


def test_refuses_to_overwrite_an_input(tmp_path, csv_file):
    data = csv_file()
    before = data.read_bytes()
    r = run("identify", str(data), "--inputs", "u1", "--outputs", "y1", "-o", str(data))
    assert r.returncode == 2 and "refusing to overwrite" in r.stderr
    assert data.read_bytes() == before


def test_bad_model_file_is_one_message(tmp_path, csv_file):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    r = run("simulate", str(bad), str(csv_file()), "-o", str(tmp_path / "p.csv"))
    assert r.returncode == 2 and "is not valid JSON" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "p.csv").exists()


def test_simulate_without_outputs_in_data_uses_model_x0(tmp_path, small_data):
    from tendonkit.dataset import write_csv

    truth, train, _ = small_data
    model = truth.save(tmp_path / "truth.json")
    e = train.experiments[0]
    data = write_csv(tmp_path / "u.csv", {"t": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1]})
    pred = tmp_path / "p.csv"
    assert main(["simulate", str(model), str(data), "-o", str(pred)]) == 0
    got = np.loadtxt(pred, delimiter=",", skiprows=1)
    from tendonkit.simulate import simulate

    np.testing.assert_allclose(got[:, 1:], simulate(truth, e.u, initial="model"), atol=1e-12)
    r = run("simulate", str(model), str(data), "-o", str(pred), "--initial", "estimate")
    assert r.returncode == 2 and "needs the model's outputs" in r.stderr


def test_plugins_lists_builtins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for name in ("n4sid", "arx", "sindyc"):
        assert f"  {name}" in out


@pytest.mark.parametrize("argv", [["--help"], ["identify", "--help"]])
def test_help_exits_zero(argv):
    r = run(*argv)
    assert r.returncode == 0 and "usage: tendonkit" in r.stdout


def test_identify_lowpass_filters_the_outputs_first(tmp_path, csv_file):
    """``--lowpass`` = identifying on :func:`tendonkit.preprocess.lowpass` data (paper §II)."""
    from tendonkit.manager import identifiers
    from tendonkit.preprocess import lowpass
    from tendonkit.schema import Model

    data = csv_file()
    model, summary = tmp_path / "m.json", tmp_path / "s.json"
    args = ["identify", str(data), "--inputs", "u1,u2", "--outputs", "y1,y2", "-o", str(model)]
    assert main([*args, "--lowpass", "2", "--json", str(summary)]) == 0
    got = Model.load(model)
    want = (
        identifiers()
        .get("arx")
        .create()
        .identify(lowpass(Dataset.from_csv(data, ["u1", "u2"], ["y1", "y2"]), 2.0))
    )
    for a, b in zip(got.representation.A, want.representation.A, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)
    assert "low-pass filtered at 2 Hz" in got.provenance.notes
    assert json.loads(summary.read_text())["lowpass_hz"] == 2.0
    # the paper's cut-off, read literally: 0.001 rad/sample at dt = 0.05 s
    assert main([*args, "--lowpass", "paper", "--json", str(summary)]) == 0
    assert json.loads(summary.read_text())["lowpass_hz"] == pytest.approx(
        0.001 / (2 * np.pi * 0.05)
    )
    # bad values are listed with the other problems
    r = run(*args[:-2], "-o", str(tmp_path / "no" / "m.json"), "--lowpass", "50")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "Nyquist frequency 10 Hz, found 50" in r.stderr
    assert "the folder of output" in r.stderr  # every problem at once
    r = run(*args, "--lowpass", "fast")
    assert r.returncode == 2 and "'paper' or 'paper-matlab', found 'fast'" in r.stderr


def _identify(tmp_path, data, *extra: str) -> int:
    return main(
        ["identify", str(data), "--method", "arx", "--inputs", "u1,u2", "--outputs", "y1,y2",
         "--option", "na=4", "--option", "nb=4", *extra]
    )  # fmt: skip


def test_two_outputs_of_one_command_never_share_a_file(tmp_path, csv_file, capsys):
    data = csv_file()
    same = tmp_path / "m.json"
    assert _identify(tmp_path, data, "-o", str(same), "--json", str(same)) == 2
    assert "-o and --json name the same file" in capsys.readouterr().err
    assert not same.exists()
    model = tmp_path / "model.json"
    assert _identify(tmp_path, data, "-o", str(model)) == 0
    capsys.readouterr()
    assert main(["compare", str(data), str(model), "--json", str(same), "--plot", str(same)]) == 2
    assert "--json and --plot name the same path" in capsys.readouterr().err
    assert not same.exists()
    args = ["diagnose", str(data), str(data), "--inputs", "u1,u2", "--outputs", "y1,y2"]
    assert main([*args, "--json", str(same), "--report", str(same)]) == 2
    assert "--json and --report name the same path" in capsys.readouterr().err


def test_a_record_no_longer_than_the_models_lags_is_refused_not_scored(tmp_path, csv_file, capsys):
    """An ARX simulation copies its first lags from the measured outputs: three samples of an
    ARX(4, 4) would have scored 100 %."""
    data = csv_file()
    model = tmp_path / "m.json"
    assert _identify(tmp_path, data, "-o", str(model)) == 0
    lines = data.read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:4]) + "\n")  # header and three samples
    capsys.readouterr()
    assert main(["compare", str(short), str(model)]) == 2
    err = capsys.readouterr().err
    assert "starts from the first 4 measured samples" in err and "short (3 samples)" in err
    # a k-step prediction copies the same lags; with an initialisation window the window rules
    assert main(["compare", str(short), str(model), "--k", "2"]) == 2
    assert "first 4 measured samples" in capsys.readouterr().err
    assert main(["compare", str(short), str(model), "--init-window", "2"]) == 0


def test_a_state_space_whose_initial_state_fits_the_record_exactly_is_refused():
    from tendonkit.compare import compare
    from tendonkit.dataset import Experiment
    from tendonkit.errors import DataError
    from tendonkit.testsystems import random_state_space

    model = random_state_space(4, 2, 2, seed=1)  # 4 states, 2 outputs: 2 samples fit exactly
    rng = np.random.default_rng(0)
    exp = Experiment(
        t=np.arange(2) * model.dt, u=rng.normal(size=(2, 2)), y=rng.normal(size=(2, 2))
    )
    data = Dataset(inputs=model.input_names, outputs=model.output_names, experiments=(exp,),
                   dt=model.dt)  # fmt: skip
    with pytest.raises(DataError, match="fits its 4 initial states"):
        compare([model], data)
    longer = Experiment(
        t=np.arange(3) * model.dt, u=rng.normal(size=(3, 2)), y=rng.normal(size=(3, 2))
    )
    res = compare([model], data.with_experiments([longer]))
    assert res["models"][0]["mean_fit"] < 99.0


def test_the_time_column_is_read_in_seconds_whatever_its_unit(tmp_path):
    from tendonkit.dataset import write_csv
    from tendonkit.errors import DataError

    t = np.arange(50) * 30.0  # 30 ms steps written in milliseconds
    cols = {"t": t, "u": np.sin(t / 100.0), "y": np.cos(t / 100.0)}
    path = write_csv(tmp_path / "ms.csv", cols, units={"t": "ms"})
    assert path.read_text().startswith("t [ms],")
    ds = Dataset.from_csv(path, ["u"], ["y"])
    assert ds.dt == pytest.approx(0.03) and ds.experiments[0].t[-1] == pytest.approx(1.47)
    odd = write_csv(tmp_path / "odd.csv", cols, units={"t": "furlong", "u": "V"})
    with pytest.raises(DataError, match="time column 't' is in 'furlong'"):
        Dataset.from_csv(odd, ["u"], ["y"])


def test_diagnose_refuses_its_training_data_as_validation_data(tmp_path, csv_file, capsys):
    data = csv_file()
    copy = tmp_path / "copy.csv"
    copy.write_bytes(data.read_bytes())
    for valid in (data, copy):
        code = main(["diagnose", str(data), str(valid), "--inputs", "u1,u2", "--outputs", "y1,y2"])
        assert code == 2
        assert "are the training data" in capsys.readouterr().err


def test_a_file_system_refusal_no_check_foresaw_is_one_message(tmp_path, monkeypatch, capsys):
    import tendonkit.cli.robot as robot

    def refused(out, **kwargs):
        raise PermissionError(13, "Permission denied", str(out))

    monkeypatch.setattr(robot, "run_demo", refused)
    assert main(["demo", "--out", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tendonkit: error: cannot use") and "Permission denied" in err
    assert "Traceback" not in err


def test_diagnose_refuses_a_validation_record_the_baseline_reads_whole(tmp_path, csv_file, capsys):
    data = csv_file()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(data.read_text().splitlines()[:4]) + "\n")  # three samples
    args = ["diagnose", str(data), str(short), "--inputs", "u1,u2", "--outputs", "y1,y2"]
    assert main([*args, "--method", "arx", "--option", "na=4", "--option", "nb=4"]) == 2
    err = capsys.readouterr().err
    assert "leaves nothing to test in the validation record(s) 'short' (3)" in err, err


def test_the_parser_reports_bad_values_outside_main_too(capsys):
    from tendonkit.cli.app import build_parser
    from tendonkit.cli.common import Parser

    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["diagnose", "a", "b", "--inputs", "u", "--outputs", "y",
                                   "--alpha", "x"])  # fmt: skip
    assert exc.value.code == 2 and "--alpha: invalid float value" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:  # --help ends the parse: nothing is left behind
        build_parser().parse_args(["diagnose", "--alpha", "x", "--help"])
    assert exc.value.code == 0 and Parser.bad_values == []


def test_every_value_argparse_cannot_use_is_listed_at_once(tmp_path, capsys):
    """argparse stops at the first bad value; every one is listed (with a missing argument)."""
    with pytest.raises(SystemExit) as exc:
        main(["diagnose", "a.csv", "b.csv", "--alpha", "x", "--seed", "y", "--jobs", "z"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    for needle in ("--alpha: invalid float value: 'x'", "--seed: a seed is a whole number",
                   "--jobs: invalid int value: 'z'", "required: --inputs, --outputs"):  # fmt: skip
        assert needle in err, needle
    with pytest.raises(SystemExit) as exc:
        main(["mpc", "m.json", "--reference", "spiral", "--duration", "-2", "--R", "abc"])
    err = capsys.readouterr().err
    assert exc.value.code == 2
    for needle in ("--reference: invalid choice: 'spiral'", "--duration: expected a finite",
                   "--R: invalid float value: 'abc'"):  # fmt: skip
        assert needle in err, needle


def test_collect_checks_radii_in_the_unit_they_are_given(tmp_path, capsys):
    out = tmp_path / "c.csv"
    assert main(["collect", "--protocol", "circles", "--radii", "100", "2", "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--radii: 100 cm is outside 0.01 to 15 cm" in err and "1.0" not in err
    assert "names no radius" not in err  # the refused radius says why
    assert not out.exists()


def test_a_model_no_better_than_the_mean_warns(tmp_path):
    """A dead time of 30 samples and the default ARX(8, 8, 1): the model was written with a
    training fit of -0.6 % and nothing said."""
    from tendonkit.dataset import write_csv

    rng = np.random.default_rng(1)
    n = 2000
    u = np.repeat(rng.choice([-1.0, 1.0], size=n // 10 + 1), 10)[:n]
    y = np.zeros(n)
    for k in range(30, n):
        y[k] = 1.5 * y[k - 1] - 0.7 * y[k - 2] + 0.1 * u[k - 30]
    data = write_csv(tmp_path / "d.csv", {"t": 0.01 * np.arange(n), "u": u, "y": y})
    out, summary = tmp_path / "m.json", tmp_path / "s.json"
    r = run("identify", str(data), "--inputs", "u", "--outputs", "y", "-o", str(out),
            "--json", str(summary))  # fmt: skip
    assert r.returncode == 0 and out.exists()
    assert "warning: the arx model's free run explains its own training data no better" in r.stderr
    assert "nk 'auto'" in json.loads(summary.read_text())["warnings"][0]


def test_inputs_recorded_twice_are_a_warning_not_a_silent_split(tmp_path):
    from tendonkit.dataset import write_csv

    rng = np.random.default_rng(2)
    u = rng.standard_normal(500)
    y = np.zeros(500)
    for k in range(1, 500):
        y[k] = 0.8 * y[k - 1] + 0.5 * u[k - 1]
    data = write_csv(tmp_path / "d.csv", {"t": np.arange(500.0), "u": u, "v": u, "y": y})
    out, summary = tmp_path / "m.json", tmp_path / "s.json"
    r = run("identify", str(data), "--inputs", "u,v", "--outputs", "y", "-o", str(out),
            "--json", str(summary))  # fmt: skip
    assert r.returncode == 0 and out.exists()
    assert "tendonkit: warning: the inputs u, v are linearly dependent" in r.stderr
    assert "(v = 1·u + 0)" in json.loads(summary.read_text())["warnings"][0]
