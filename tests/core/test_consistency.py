"""A model meeting data of another sample time, and a model that diverges: errors, never silence."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.compare import compare, render_compare
from tendonkit.dataset import Dataset, write_csv
from tendonkit.errors import DataError
from tendonkit.schema import Model, Signal, StateSpace
from tendonkit.simulate import divergence, simulate_dataset
from tendonkit.testsystems import random_state_space, simulate_truth


def _csv(tmp_path, ds: Dataset, name: str = "d.csv"):
    e = ds.experiments[0]
    cols = {"t": e.t}
    cols.update({n: e.u[:, j] for j, n in enumerate(ds.inputs)})
    cols.update({n: e.y[:, j] for j, n in enumerate(ds.outputs)})
    return write_csv(tmp_path / name, cols)


@pytest.fixture
def fast_data():
    """Data of the 0.03 s test system, but sampled at 0.01 s."""
    truth = random_state_space(3, 2, 2, seed=2, dt=0.01)
    data, _ = simulate_truth(truth, 600, noise=0.0, seed=1)
    return data


def test_a_model_meeting_data_of_another_sample_time_is_an_error(tmp_path, capsys, fast_data):
    model = random_state_space(3, 2, 2, seed=2, dt=0.03)
    assert model.input_names == list(fast_data.inputs)
    with pytest.raises(DataError, match=r"sample time 0\.03 s but the data are sampled at 0\.01 s"):
        simulate_dataset(model, fast_data)
    path = tmp_path / "m.json"
    model.save(path)
    data = _csv(tmp_path, fast_data)
    for args in (["simulate", path, data, "-o", tmp_path / "o.csv"], ["compare", data, path]):
        code = main([str(a) for a in args])
        err = capsys.readouterr().err
        assert code == 2 and "sample time 0.03 s" in err and "0.01 s" in err, err
    assert not (tmp_path / "o.csv").exists()


def _unstable() -> Model:
    return Model(
        name="unstable",
        dt=0.01,
        inputs=(Signal("u1"), Signal("u2")),
        outputs=(Signal("y1"), Signal("y2")),
        representation=StateSpace(
            A=np.diag([1.08, 0.5]), B=np.eye(2), C=np.eye(2), D=np.zeros((2, 2))
        ),
    )


def test_divergence_is_located():
    y = np.ones((100, 1))
    y[40:] = 1e9
    assert divergence(y, np.ones((100, 1)) * np.linspace(0, 1, 100)[:, None]) == 40
    y[20] = np.nan
    assert divergence(y, np.ones((10, 1))) == 20
    assert divergence(np.ones((5, 2)), np.ones((5, 2))) is None


def test_a_diverging_simulation_is_reported_not_written(tmp_path, capsys, fast_data):
    model = _unstable()
    path = tmp_path / "m.json"
    model.save(path)
    e = fast_data.experiments[0]
    n = 4000
    data = write_csv(
        tmp_path / "d.csv",
        {"t": 0.01 * np.arange(n), "u1": np.resize(e.u[:, 0], n), "u2": np.resize(e.u[:, 1], n)},
    )
    code = main(["simulate", str(path), str(data), "-o", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "diverged at sample" in err
    assert not (tmp_path / "o.csv").exists()


def test_compare_marks_a_diverged_model_and_writes_strict_json(tmp_path, capsys, fast_data):
    stable = random_state_space(3, 2, 2, seed=2, dt=0.01)
    data = Dataset.from_arrays(
        np.resize(fast_data.u, (4000, 2)),
        np.resize(fast_data.y, (4000, 2)),
        dt=0.01,
        inputs=fast_data.inputs,
        outputs=fast_data.outputs,
    )
    res = compare([stable, _unstable()], data, names=["stable", "unstable"])
    bad = res["models"][1]
    assert bad["diverged_at_sample"] > 0 and bad["mean_fit"] is None
    assert res["models"][0].get("diverged_at_sample") is None
    assert "unstable: diverged at sample" in render_compare(res)
    paths = [tmp_path / "s.json", tmp_path / "u.json"]
    stable.save(paths[0])
    _unstable().save(paths[1])
    csv = _csv(tmp_path, data)
    code = main(["compare", str(csv), *map(str, paths), "--json", str(tmp_path / "r.json")])
    assert code == 0, capsys.readouterr().err
    text = (tmp_path / "r.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    assert json.loads(text)["models"][1]["diverged_at_sample"] > 0
