"""Units travel from the CSV header into the model and are checked where model meets data.

Issue 15, point 2 (dt, names *and units* checked in simulate / compare / diagnose / export /
mpc) and issue 16, point 3 (models identified from the CLI carried no units).  A header cell
``q1 [rad]`` is column ``q1`` in ``rad``; ``identify --units`` gives units a header lacks.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.dataset import Dataset, split_header, write_csv
from tendonkit.errors import DataError
from tendonkit.schema import Model
from tendonkit.simulate import simulate_dataset

UNITS = {"t": "s", "u1": "N", "u2": "N", "y1": "rad", "y2": "rad"}


def run(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


@pytest.fixture
def with_units(tmp_path, small_data):
    """Write the small data as CSV with the given units in its header."""

    def make(units: dict[str, str], name: str = "data.csv") -> Path:
        e = small_data[1].experiments[0]
        cols = {"t": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1], "y1": e.y[:, 0], "y2": e.y[:, 1]}
        return write_csv(tmp_path / name, cols, units)

    return make


def identify(capsys, tmp_path, data, *extra) -> Path:
    out = tmp_path / "m.json"
    code, _, err = run(
        capsys, "identify", data, "--inputs", "u1,u2", "--outputs", "y1,y2",
        "--option", "na=2", "--option", "nb=2", "-o", out, *extra,
    )  # fmt: skip
    assert code == 0, err
    return out


def test_the_header_convention_reads_names_and_units(with_units):
    path = with_units(UNITS)
    assert path.read_text().splitlines()[0] == "t [s],u1 [N],u2 [N],y1 [rad],y2 [rad]"
    ds = Dataset.from_csv(path, ["u1", "u2"], ["y1", "y2"])
    assert ds.units == {"u1": "N", "u2": "N", "y1": "rad", "y2": "rad"}
    assert split_header("x [m/s^2]") == ("x", "m/s^2")
    assert split_header("[weird") == ("[weird", "")


def test_identify_stores_the_units_and_simulate_writes_them(capsys, tmp_path, with_units):
    data = with_units(UNITS)
    model = Model.load(identify(capsys, tmp_path, data))
    assert [s.unit for s in model.inputs] == ["N", "N"]
    assert [s.unit for s in model.outputs] == ["rad", "rad"]
    out = tmp_path / "sim.csv"
    code, _, err = run(capsys, "simulate", tmp_path / "m.json", data, "-o", out)
    assert code == 0, err
    assert out.read_text().splitlines()[0] == "t,y1 [rad],y2 [rad]"


def test_units_given_on_the_command_line(capsys, tmp_path, csv_file):
    data = csv_file()
    path = identify(capsys, tmp_path, data, "--units", "u1=N,u2=N,y1=deg,y2=deg")
    model = Model.load(path)
    assert [s.unit for s in model.outputs] == ["deg", "deg"]


@pytest.mark.parametrize(
    ("units", "needle"),
    [
        ("y1=deg", "the header says 'rad', the units given say 'deg'"),
        ("q9=rad", "'q9', which is not an input or output"),
        ("y1", "NAME=UNIT pairs"),
        ("y1=rad,y1=rad", "'y1' twice"),
        ("u1=N[m]", "brackets"),
    ],
)
def test_bad_units_on_the_command_line(capsys, tmp_path, with_units, units, needle):
    data = with_units(UNITS)
    before = data.read_bytes()
    code, _, err = run(
        capsys, "identify", data, "--inputs", "u1,u2", "--outputs", "y1,y2",
        "-o", tmp_path / "m.json", "--units", units,
    )  # fmt: skip
    assert code == 2 and needle in err, err
    assert not (tmp_path / "m.json").exists() and data.read_bytes() == before


def test_simulate_and_compare_refuse_data_in_other_units(capsys, tmp_path, with_units):
    model = identify(capsys, tmp_path, with_units(UNITS))
    deg = with_units({**UNITS, "y1": "deg", "u2": "kN"}, name="deg.csv")
    out = tmp_path / "sim.csv"
    code, _, err = run(capsys, "simulate", model, deg, "-o", out)
    assert code == 2 and "disagree on units" in err, err
    assert "y1: the model's is 'rad'" in err and "u2: the model's is 'N'" in err
    assert not out.exists()
    code, _, err = run(capsys, "compare", deg, model)
    assert code == 2 and "disagree on units" in err and "y1" in err, err
    # in Python: a DataError from every function that aligns a model with data
    with pytest.raises(DataError, match="disagree on units"):
        simulate_dataset(Model.load(model), Dataset.from_csv(deg, ["u1", "u2"], ["y1", "y2"]))


def test_data_without_units_meet_any_model(capsys, tmp_path, with_units, csv_file):
    model = identify(capsys, tmp_path, with_units(UNITS))
    code, _, err = run(capsys, "compare", csv_file(), model)
    assert code == 0, err


def test_two_files_that_disagree_on_a_unit(with_units):
    a = with_units(UNITS, "a.csv")
    b = with_units({**UNITS, "y2": "deg"}, "b.csv")
    with pytest.raises(DataError, match=r"column 'y2' is in 'rad' in .*a.csv but in 'deg'"):
        Dataset.from_csv([a, b], ["u1", "u2"], ["y1", "y2"])


def test_a_unit_with_a_separator_in_the_header_is_a_problem(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("t,u1 [N;m],y1\n0,1,2\n0.1,2,3\n0.2,3,5\n")
    with pytest.raises(DataError, match="unit of column 'u1'"):
        Dataset.from_csv(path, ["u1"], ["y1"])


def test_export_refuses_joint_angles_not_in_rad(capsys, tmp_path, small_data):
    e = small_data[1].experiments[0]
    cols = {"t": e.t, "u1": e.u[:, 0], "u2": e.u[:, 1], "q1": e.y[:, 0], "q2": e.y[:, 1]}
    data = write_csv(tmp_path / "deg.csv", cols, {"q1": "deg", "q2": "deg"})
    model = tmp_path / "m.json"
    code, _, err = run(
        capsys, "identify", data, "--inputs", "u1,u2", "--outputs", "q1,q2", "-o", model
    )
    assert code == 0, err
    code, _, err = run(capsys, "export", model, "-o", tmp_path / "m.fmu")
    assert code == 2 and "computes in rad" in err and "q1 [deg]" in err, err
    assert not (tmp_path / "m.fmu").exists()


def test_mpc_refuses_a_model_in_other_units(capsys, tmp_path):
    rng = np.random.default_rng(0)
    n = 400
    cols = {"t": np.arange(n) * 0.03}
    cols |= {f"u{i}": 100 + rng.normal(0, 5, n) for i in range(1, 5)}
    cols |= {"q1": rng.normal(0, 1, n), "q2": rng.normal(0, 1, n)}
    data = write_csv(tmp_path / "d.csv", cols, {"q1": "deg", "q2": "deg", "u1": "kN"})
    model = tmp_path / "m.json"
    code, _, err = run(
        capsys, "identify", data, "--inputs", "u1,u2,u3,u4", "--outputs", "q1,q2", "-o", model
    )
    assert code == 0, err
    code, _, err = run(capsys, "mpc", model, "--reference", "circle", "--duration", "1")
    assert code == 2 and "u1 [kN]" in err and "q1 [deg]" in err, err


def test_the_collected_csv_carries_units(tmp_path, capsys):
    out = tmp_path / "c.csv"
    code, _, err = run(
        capsys, "collect", "--protocol", "random", "--duration", "3", "-o", out, "--seed", "1"
    )
    assert code == 0, err
    header = out.read_text().splitlines()[0].split(",")
    assert header[:6] == ["t [s]", "u1 [N]", "u2 [N]", "u3 [N]", "u4 [N]", "T1 [N]"]
    assert "q1 [rad]" in header and "ee_x [m]" in header and "q1_true [rad]" in header
    model = tmp_path / "m.json"
    code, _, err = run(
        capsys, "identify", out, "--inputs", "u1,u2,u3,u4", "--outputs", "q1,q2", "-o", model
    )
    assert code == 0, err
    saved = json.loads(model.read_text())
    assert {s["unit"] for s in saved["inputs"]} == {"N"}
    assert {s["unit"] for s in saved["outputs"]} == {"rad"}
