"""Dataset loading and validation: every problem reported at once."""

from __future__ import annotations

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.dataset import Dataset, write_csv
from tendonkit.errors import DataError


def _write(tmp_path, name, header, rows):
    path = tmp_path / name
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return path


def test_loads_columns_by_name_and_keeps_extras(csv_file):
    ds = Dataset.from_csv(csv_file(), ["u2", "u1"], ["y1"])
    assert ds.inputs == ("u2", "u1") and ds.outputs == ("y1",)
    assert ds.dt == pytest.approx(0.05)
    assert "extra" in ds.experiments[0].extra and "y2" in ds.experiments[0].extra
    assert ds.columns[:3] == ["u2", "u1", "y1"]


def test_every_problem_is_listed_at_once(tmp_path):
    rows = [[0.0, 1, 5, "x"], [0.1, 1, float("nan"), 2], [0.1, 1, 3, 3], [0.5, 1, 2, 4]]
    path = _write(tmp_path, "bad.csv", ["t", "F1", "pan", "pan"], rows)
    with pytest.raises(DataError) as info:
        Dataset.from_csv(path, ["F1", "F5"], ["pan", "tilt"])
    text = str(info.value)
    assert "duplicate column names in the header: ['pan']" in text
    assert "input column 'F5' is not in the file. Columns: t, F1, pan, pan." in text
    assert "output column 'tilt' is not in the file" in text
    assert len(info.value.problems) == 3


def test_time_problems_state_the_tolerance(tmp_path):
    path = _write(
        tmp_path, "t.csv", ["t", "u", "y"], [[0, 1, 2], [0.1, 2, 3], [0.25, 3, 1], [0.35, 1, 2]]
    )
    with pytest.raises(DataError, match=r"differs from the median 0.1 s by more than 1%"):
        Dataset.from_csv(path, ["u"], ["y"])
    path = _write(tmp_path, "t2.csv", ["t", "u", "y"], [[0, 1, 2], [0.1, 2, 3], [0.1, 3, 1]])
    with pytest.raises(DataError, match="must increase"):
        Dataset.from_csv(path, ["u"], ["y"])


def test_a_ragged_row_is_reported_once_and_the_rest_still_checked(tmp_path):
    """A row with too many fields is one problem, not also a 'missing time'; the time checks
    still run on the rows that were read, numbered as in the file."""
    rows = [[0.0, 1, 2], [0.1, 2, 3, 9], [0.2, 3, 1], [0.15, 1, 2], ["x", 1, 2], [0.5, 1, 2]]
    path = _write(tmp_path, "r.csv", ["t", "u", "y"], rows)
    with pytest.raises(DataError) as info:
        Dataset.from_csv(path, ["u"], ["y"])
    assert info.value.problems == [
        f"{path}: 1 rows do not have 3 fields (rows 3).",
        f"{path}: non-numeric values: row 6, column 't': 'x'.",
        f"{path}: time column 't' must increase; row 5 has t = 0.15 s after 0.2 s.",
    ]
    path = _write(tmp_path, "n.csv", ["t", "u", "y"], [[0.0, 1, 2], ["nan", 2, 3], [0.2, 3, 1]])
    with pytest.raises(DataError, match="time column 't' has missing or non-numeric values"):
        Dataset.from_csv(path, ["u"], ["y"])


def test_nan_constant_and_non_numeric_values(tmp_path):
    rows = [[0.0, 1, 2, "abc"], [0.1, 1, float("nan"), 1], [0.2, 1, 3, 2]]
    path = _write(tmp_path, "v.csv", ["t", "u", "y", "z"], rows)
    with pytest.raises(DataError) as info:
        Dataset.from_csv(path, ["u", "z"], ["y"])
    text = str(info.value)
    assert "non-numeric values: row 2, column 'z': 'abc'" in text
    path = _write(
        tmp_path, "w.csv", ["t", "u", "y"], [[0.0, 1, 2], [0.1, 1, float("nan")], [0.2, 1, 3]]
    )
    with pytest.raises(DataError) as info:
        Dataset.from_csv(path, ["u"], ["y"])
    # each problem names its file, and rows are counted as in the file (the header is row 1)
    assert (
        f"{path}: output 'y' has 1 NaN/inf values (first at row 3, t = 0.1 s)."
        in info.value.problems
    )
    assert f"{path}: input 'u' is constant (1); it carries no information." in info.value.problems


def test_same_column_as_input_and_output_is_refused(csv_file):
    with pytest.raises(DataError, match="used more than once"):
        Dataset.from_csv(csv_file(), ["u1"], ["u1"])


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        Dataset.from_csv(tmp_path / "nope.csv", ["u"], ["y"])


def test_several_experiments_and_split(small_data, tmp_path):
    _, train, valid = small_data
    joined = train.concat(valid)
    assert len(joined.experiments) == 2 and joined.n_samples == 2800
    a, b = joined.split(0.75)
    assert [e.n_samples for e in a.experiments] == [1500, 600]
    assert [e.n_samples for e in b.experiments] == [500, 200]
    np.testing.assert_array_equal(b.experiments[0].u, train.experiments[0].u[1500:])


def test_hash_changes_with_data(small_data):
    _, train, valid = small_data
    assert train.hash() != valid.hash()
    assert train.hash() == train.with_experiments(train.experiments).hash()


def test_write_csv_round_trip(tmp_path):
    cols = {"t": np.arange(5) * 0.1, "u": np.pi * np.arange(5), "y": np.exp(np.arange(5))}
    p = write_csv(tmp_path / "x.csv", cols)
    ds = Dataset.from_csv(p, ["u"], ["y"])
    np.testing.assert_array_equal(ds.experiments[0].y[:, 0], cols["y"])  # %.17g is exact


def test_blocked_folds_hold_each_block_out_once_and_fit_on_the_rest():
    rng = np.random.default_rng(0)
    long = tk.Dataset.from_arrays(rng.normal(size=(100, 1)), rng.normal(size=(100, 1)), 0.1,
                                  ["u"], ["y"])  # fmt: skip
    data = long.with_experiments([long.experiments[0], _cut(long.experiments[0], 30)])
    folds = data.blocked_folds(4, min_held=10, min_piece=5)
    assert len(folds) == 4
    for j, (fit, held) in enumerate(folds):
        # the 100-sample record's block j is held out; the 30-sample one's blocks are too short
        assert [e.n_samples for e in held.experiments] == [25]
        h = held.experiments[0]
        assert np.array_equal(h.u, data.experiments[0].u[25 * j : 25 * (j + 1)])
        pieces = [e for e in fit.experiments if e.n_samples != 30]
        assert sum(e.n_samples for e in pieces) == 75  # before and after the block
        held_t = set(np.round(h.t, 9))
        assert all(not held_t & set(np.round(e.t, 9)) for e in pieces)
    assert data.blocked_folds(4, min_held=40, min_piece=5) == []


def _cut(e, n):
    return tk.Experiment(t=e.t[:n], u=e.u[:n], y=e.y[:n], name="short")


def test_the_python_api_reports_bad_data_as_the_cli_does():
    """A dataset built by hand (not through from_csv/from_arrays, which check it) with a NaN
    and a constant input: identify and diagnose raise DataError listing every problem, not a
    model of zeros (n4sid) or a numerical library's error (arx)."""
    import tendonkit as tk
    from tendonkit.diagnose import diagnose

    rng = np.random.default_rng(0)
    u = np.hstack([rng.standard_normal((300, 1)), np.ones((300, 1))])
    y = rng.standard_normal((300, 1))
    y[50] = np.nan
    bad = tk.Dataset(
        inputs=("u", "c"),
        outputs=("y",),
        experiments=(tk.Experiment(t=np.arange(300.0), u=u, y=y, name="bad"),),
        dt=1.0,
    )
    for method in ("arx", "n4sid"):
        with pytest.raises(tk.DataError) as info:
            tk.identify(bad, method)
        assert info.value.problems == [
            "input 'c' is constant (1); it carries no information.",
            "output 'y' has 1 NaN/inf values (first at row 51, t = 50 s).",
        ]
    with pytest.raises(tk.DataError, match=r"training data: output 'y' has 1 NaN") as info:
        diagnose(bad, bad, alpha=2.0)
    assert len(info.value.problems) == 5  # 2 per dataset and the option


def test_inputs_that_cannot_be_told_apart_are_said_to_be():
    """An input recorded twice and a tension at a constant pretension with its antagonist
    were accepted without a word: the model split their effect by minimum norm.  Each
    dependence is named (``b = k·a + c``); over several experiments together the inputs may
    vary independently, and a constant input stays a problem of its own."""
    from tendonkit.dataset import dependent_inputs

    rng = np.random.default_rng(3)
    a, b = rng.standard_normal((2, 400))

    def data(*cols, names=("a", "b", "c")):
        u = np.column_stack(cols)
        e = tk.Experiment(t=np.arange(400.0), u=u, y=rng.standard_normal((400, 1)))
        return tk.Dataset(inputs=names[: u.shape[1]], outputs=("y",), experiments=(e,), dt=1.0)

    assert dependent_inputs(data(a, b)) is None
    said = dependent_inputs(data(a, b, 210.0 - a))
    assert said is not None and "(c = -1·a + 210)" in said and "cannot tell" in said
    said = dependent_inputs(data(a, b, a + b))
    assert said is not None and "a linear combination of a, b, c is constant" in said
    # a pair and a dependence among three more are both named, two triples apart
    c, d = rng.standard_normal((2, 400))
    names = ("a", "b", "c", "d", "e")
    said = dependent_inputs(data(a, a.copy(), c, d, c + d, names=names)) or ""
    assert "(b = 1·a + 0; a linear combination of c, d, e is constant)" in said, said
    names = ("a", "b", "c", "d", "e", "f")
    said = dependent_inputs(data(a, b, a - b, c, d, c + 2 * d, names=names)) or ""
    assert "of a, b, c is constant; a linear combination of d, e, f is constant" in said, said
    # written at a resolution (tensions of std 20 N to 1e-4 N) the dependence is still seen;
    # measured tensions (0.3 N of noise) are not dependent
    t1 = np.round(75.0 + 20.0 * a, 4)
    said = dependent_inputs(data(t1, np.round(150.0 - 0.9 * t1, 4), names=("T1", "T2")))
    assert said is not None and "(T2 = -0.9·T1 + 150)" in said, said
    noisy = 150.0 - 0.9 * t1 + rng.normal(0.0, 0.3, 400)
    assert dependent_inputs(data(t1, noisy, names=("T1", "T2"))) is None
    twice = data(a, a.copy(), names=("a", "b"))
    assert "(b = 1·a + 0)" in (dependent_inputs(twice) or "")
    # two experiments, each at its own pretension: together they tell the tendons apart
    e1, e2 = data(a, 210.0 - a).experiments[0], data(b, 190.0 - b).experiments[0]
    both = tk.Dataset(inputs=("a", "b"), outputs=("y",), experiments=(e1, e2), dt=1.0)
    assert dependent_inputs(both) is None
    # identify says so, as a TendonkitWarning, and still fits
    y = np.zeros((400, 1))
    for k in range(1, 400):
        y[k] = 0.8 * y[k - 1] + 0.5 * a[k - 1]
    same = tk.Dataset(
        inputs=("a", "b"),
        outputs=("y",),
        experiments=(tk.Experiment(t=np.arange(400.0), u=np.column_stack([a, a]), y=y),),
        dt=1.0,
    )
    with pytest.warns(tk.TendonkitWarning, match=r"inputs a, b are linearly dependent"):
        model = tk.identify(same, "arx", na=1, nb=1)
    assert model.provenance.training_fit["y"] > 99.0
