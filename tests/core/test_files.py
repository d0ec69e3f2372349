"""Files as a hostile user meets them: outputs never cost data, inputs never hang (issue 15).

Every case runs the CLI in-process and asserts exit status 2 with one message naming the problem
(no traceback), or the documented behaviour (docs/cli.md, "Files"); inputs stay byte-identical.
"""

from __future__ import annotations

import json
import os
import resource
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.dataset import Dataset, write_csv
from tendonkit.errors import DataError, OutputError
from tendonkit.files import atomic_write, json_safe, write_json


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


@pytest.fixture
def model_file(tmp_path, csv_file, capsys):
    data = csv_file()
    path = tmp_path / "m.json"
    code, _, err = run(
        capsys, "identify", data, "--method", "arx", "--inputs", "u1,u2", "--outputs", "y1,y2",
        "--option", "na=2", "--option", "nb=2", "-o", path,
    )  # fmt: skip
    assert code == 0, err
    return data, path


def snapshot(*paths: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in paths}


# -- outputs ------------------------------------------------------------------------------------


def test_output_that_is_a_folder_is_refused(capsys, tmp_path, model_file):
    data, model = model_file
    code, _, err = run(capsys, "simulate", model, data, "-o", tmp_path)
    assert code == 2 and "is a folder" in err


def test_output_device_is_refused_and_left_alone(capsys, model_file):
    data, model = model_file
    before = os.stat("/dev/null")
    code, _, err = run(capsys, "simulate", model, data, "-o", "/dev/null")
    assert code == 2 and "is a device" in err
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


def test_json_naming_an_input_never_overwrites_it(capsys, tmp_path, model_file):
    data, model = model_file
    kept = snapshot(data, model)
    code, _, err = run(capsys, "compare", data, model, "--json", data)
    assert code == 2 and "is also an input" in err
    link = tmp_path / "alias.csv"
    link.symlink_to(data)
    code, _, err = run(capsys, "compare", data, model, "--json", link)
    assert code == 2 and "is also an input" in err
    assert snapshot(data, model) == kept


def test_writing_through_a_symlink_keeps_the_link(capsys, tmp_path, model_file):
    data, model = model_file
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    code, _, err = run(capsys, "simulate", model, data, "-o", link)
    assert code == 0, err
    assert link.is_symlink() and target.read_text().startswith("t,y1,y2")


def test_new_files_follow_the_umask_and_replaced_files_keep_their_mode(tmp_path):
    old = os.umask(0o022)
    try:
        p = atomic_write(tmp_path / "a.txt", lambda q: q.write_text("x"))
        assert stat.S_IMODE(p.stat().st_mode) == 0o644
        os.chmod(p, 0o600)
        atomic_write(p, lambda q: q.write_text("y"))
        assert stat.S_IMODE(p.stat().st_mode) == 0o600 and p.read_text() == "y"
    finally:
        os.umask(old)


def test_a_failed_write_leaves_the_old_file_and_no_temporary_file(tmp_path):
    p = tmp_path / "keep.json"
    p.write_text("precious")

    def fails(q: Path) -> None:
        q.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OutputError, match="No space left on device") as info:
        atomic_write(p, fails)
    assert str(p) in str(info.value)
    assert p.read_text() == "precious" and sorted(tmp_path.iterdir()) == [p]


def test_file_size_limit_is_one_message_and_nothing_left(tmp_path):
    # RLIMIT_FSIZE: the kernel refuses to grow a file past 64 kB (EFBIG; Python ignores SIGXFSZ).
    out = tmp_path / "big.json"
    code = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (65536, 65536))\n"
        "from tendonkit.files import write_json\n"
        "from tendonkit.errors import OutputError\n"
        f"try:\n    write_json({str(out)!r}, list(range(100000)))\n"
        "except OutputError as e:\n    print(e); sys.exit(2)\n"
    )
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "File too large" in r.stdout and str(out) in r.stdout
    assert list(tmp_path.iterdir()) == []
    assert resource.getrlimit(resource.RLIMIT_FSIZE) == (soft, hard)


def test_plot_naming_an_existing_file_is_refused(capsys, tmp_path, model_file):
    data, model = model_file
    f = tmp_path / "plots"
    f.write_text("not a folder")
    code, _, err = run(capsys, "compare", data, model, "--plot", f)
    assert code == 2 and "exists and is not a folder" in err


def test_failed_command_leaves_no_empty_plot_folder(capsys, tmp_path, model_file):
    data, model = model_file
    folder = tmp_path / "figs"
    code, _, err = run(capsys, "compare", data, model, "--plot", folder, "--k", "0")
    assert code == 2 and "--k must be >= 1" in err
    assert not folder.exists()


def test_plugins_json_in_a_missing_folder(capsys, tmp_path):
    code, _, err = run(capsys, "plugins", "--json", tmp_path / "nodir" / "p.json")
    assert code == 2 and "does not exist" in err


def test_strict_json_has_no_nan_or_infinity(tmp_path):
    p = write_json(
        tmp_path / "s.json", {"a": float("-inf"), "b": [np.nan, 1.5], "c": np.float64(2)}
    )
    text = p.read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text) == {"a": None, "b": [None, 1.5], "c": 2.0}
    assert json_safe((np.inf,)) == [None]


# -- options that size work --------------------------------------------------------------------


@pytest.mark.parametrize("k", ["100000", "1000000000"])
def test_huge_k_is_refused_up_front(capsys, tmp_path, model_file, k):
    data, model = model_file
    code, _, err = run(capsys, "simulate", model, data, "-o", tmp_path / "o.csv", "--k", k)
    assert code == 2 and "--k must be at most the number of samples" in err
    code, _, err = run(capsys, "compare", data, model, "--k", k)
    assert code == 2 and "--k must be at most the number of samples" in err


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["collect", "--protocol", "random", "--duration", "inf"], "finite number > 0"),
        (["collect", "--protocol", "circles", "--laps", "0"], "finite number > 0"),
        (["collect", "--protocol", "random", "--seed", "-1"], "a seed is a whole number"),
        (["demo", "--seed", "-1"], "a seed is a whole number"),
    ],
)
def test_bad_sizes_and_seeds_are_refused(capsys, tmp_path, args, needle):
    with pytest.raises(SystemExit) as info:
        main([*args, "-o", str(tmp_path / "x.csv")] if args[0] == "collect" else args)
    assert info.value.code == 2
    assert needle in capsys.readouterr().err


def test_effects_naming_nothing_is_refused(capsys, tmp_path, csv_file):
    data = csv_file()
    code, _, err = run(
        capsys, "diagnose", data, data, "--inputs", "u1,u2", "--outputs", "y1,y2",
        "--effects", ",",
    )  # fmt: skip
    assert code == 2 and "names no effect" in err


# -- CSV inputs -----------------------------------------------------------------------------


def test_fifo_is_refused_without_blocking(capsys, tmp_path, model_file):
    _, model = model_file
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    code, _, err = run(capsys, "simulate", model, fifo, "-o", tmp_path / "o.csv")
    assert code == 2 and "FIFO" in err


def _table(tmp_path: Path, text: str, name: str = "d.csv", encoding: str = "utf-8") -> Path:
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


ROWS = "".join(f"{0.1 * k:.1f},{np.sin(k):.6f},{np.cos(0.3 * k):.6f}\n" for k in range(50))


def test_trailing_blank_lines_are_fine_and_inner_ones_are_located(tmp_path):
    ok = _table(tmp_path, "t,u,y\n" + ROWS + "\n\n")
    assert Dataset.from_csv(ok, ["u"], ["y"]).n_samples == 50
    lines = ROWS.splitlines(keepends=True)
    bad = _table(tmp_path, "t,u,y\n" + "".join(lines[:10]) + "\n" + "".join(lines[10:]), "b.csv")
    with pytest.raises(DataError, match=r"blank lines inside the data \(rows 12\)"):
        Dataset.from_csv(bad, ["u"], ["y"])


def test_semicolon_file_gets_a_delimiter_hint(tmp_path):
    p = _table(tmp_path, "t;u;y\n" + ROWS.replace(",", ";"))
    with pytest.raises(DataError, match="seems separated by ';'"):
        Dataset.from_csv(p, ["u"], ["y"])


def test_utf16_with_and_without_bom(tmp_path):
    text = "t,u,y\n" + ROWS
    assert Dataset.from_csv(_table(tmp_path, text, "a.csv", "utf-16"), ["u"], ["y"]).n_samples == 50
    with pytest.raises(DataError, match="UTF-16 without a byte-order mark"):
        Dataset.from_csv(_table(tmp_path, text, "b.csv", "utf-16-le"), ["u"], ["y"])


def test_missing_time_column_mentions_time_option(capsys, tmp_path, model_file):
    _, model = model_file
    p = _table(tmp_path, "time,u1,u2\n" + ROWS)
    code, _, err = run(capsys, "simulate", model, p, "-o", tmp_path / "o.csv")
    assert code == 2 and "--time" in err


def test_simulate_writes_the_time_column_under_its_own_name(capsys, tmp_path, small_data):
    e = small_data[1].experiments[0]
    data = write_csv(tmp_path / "d.csv", {"sec": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1],
                                          "y1": e.y[:, 0], "y2": e.y[:, 1]})  # fmt: skip
    model = tmp_path / "m.json"
    args = ["--inputs", "u1,u2", "--outputs", "y1,y2", "--time", "sec"]
    assert run(capsys, "identify", data, *args, "-o", model)[0] == 0
    code, _, err = run(capsys, "simulate", model, data, "--time", "sec", "-o", tmp_path / "o.csv")
    assert code == 0, err
    assert (tmp_path / "o.csv").read_text().splitlines()[0] == "sec,y1,y2"


def test_a_huge_spike_is_a_corrupt_sample(tmp_path):
    lines = ROWS.splitlines()
    t, _, y = lines[5].split(",")
    lines[5] = f"{t},1e300,{y}"  # file row 7 (after the header)
    p = _table(tmp_path, "t,u,y\n" + "\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"beyond ±1e\+150 \(row 7\)"):
        Dataset.from_csv(p, ["u"], ["y"])


def test_csv_names_that_a_header_cannot_hold(tmp_path):
    for name in ("a,b", "q\n1", 'x"y', ""):
        with pytest.raises(DataError, match="cannot be written to a CSV header"):
            write_csv(tmp_path / "o.csv", {name: np.zeros(3)})
    assert not (tmp_path / "o.csv").exists()


def test_mpc_horizon_and_sample_time_are_checked_up_front(capsys, tmp_path):
    from tendonkit.mpc.examples import two_mode_model

    model = tmp_path / "m.json"
    two_mode_model().save(model)
    code, _, err = run(capsys, "mpc", model, "--reference", "petal", "--horizon", "100000")
    assert code == 2 and "--horizon must be from 1 to 300 samples" in err
    fast = tmp_path / "fast.json"
    two_mode_model().replace(dt=0.01).save(fast)
    code, _, err = run(capsys, "mpc", fast, "--reference", "petal")
    assert code == 2 and "sample time 0.01 s" in err


def test_report_naming_an_existing_file_is_refused(capsys, tmp_path, csv_file):
    data = csv_file()
    report = tmp_path / "report"
    report.write_text("a file")
    code, _, err = run(
        capsys, "diagnose", data, data, "--inputs", "u1,u2", "--outputs", "y1,y2",
        "--report", report,
    )  # fmt: skip
    assert code == 2 and "--report" in err and "exists and is not a folder" in err
    assert report.read_text() == "a file"


def test_na_0_is_a_fir_model_as_documented(capsys, tmp_path, csv_file):
    out = tmp_path / "fir.json"
    code, _, err = run(
        capsys, "identify", csv_file(), "--inputs", "u1,u2", "--outputs", "y1,y2",
        "--option", "na=0", "--option", "nb=20", "-o", out,
    )  # fmt: skip
    assert code == 0, err
    rep = json.loads(out.read_text())["representation"]
    assert rep["kind"] == "arx" and rep["A"] == [] and len(rep["B"]) == 20


def test_compare_plot_works_for_any_model(capsys, tmp_path, model_file):
    data, model = model_file  # outputs y1, y2: no robot joints to reconstruct
    figs = tmp_path / "figs"
    code, _, err = run(capsys, "compare", data, model, "--plot", figs)
    assert code == 0, err
    # a linear model also gets its Bode plot over the data's spectral estimate
    assert sorted(p.name for p in figs.glob("*.png")) == ["bode_compare.png", "outputs_compare.png"]


def test_long_diagnosis_shows_progress_over_every_stage(capsys, small_data):
    from tendonkit.diagnose import diagnose

    _, train, valid = small_data
    diagnose(train, valid, effects=["input_delay"], options={"na": 2, "nb": 2}, progress=True)
    err = capsys.readouterr().err
    assert "diagnose: baseline" in err and "diagnose: input_delay" in err
