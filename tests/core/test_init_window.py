"""The benchmarks' official protocol (issue 17, point 4): an initialisation window, then the score.

With ``init_window=N`` the initial state may use the first N measured samples only, and the
fit and RMSE are computed on the samples after them.  The tests change the measured outputs
after the window and require the simulation not to move; they check the scores against a
hand computation on the scored samples; and the CLI's ``--init-window``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import tendonkit as tk
from tendonkit.cli import main
from tendonkit.compare import compare, rmse, score
from tendonkit.errors import DataError
from tendonkit.metrics import fit
from tendonkit.simulate import simulate
from tendonkit.testsystems import random_state_space, simulate_truth


@pytest.fixture(scope="module")
def system():
    truth = random_state_space(4, 2, 2, seed=3)
    data = simulate_truth(truth, 800, noise=0.02, seed=4)[0]
    models = {
        "n4sid": tk.identify(data, "n4sid", order=4),
        "arx": tk.identify(data, "arx", na=3, nb=3, nk=1),
    }
    return data, models


@pytest.mark.parametrize("which", ["n4sid", "arx"])
@pytest.mark.parametrize("window", [2, 20])
def test_only_the_window_informs_the_initial_state(system, which, window):
    data, models = system
    model = models[which]
    e = data.experiments[0]
    y_other = e.y.copy()
    y_other[window:] += 100.0  # what comes after the window must not matter
    a = simulate(model, e.u, y=e.y, initial="estimate", init_window=window)
    b = simulate(model, e.u, y=y_other, initial="estimate", init_window=window)
    np.testing.assert_array_equal(a, b)
    # and without a window the state-space estimate does read further (default 50 samples)
    if which == "n4sid":
        c = simulate(model, e.u, y=y_other, initial="estimate")
        assert np.abs(c - a).max() > 1.0


def test_scores_are_computed_after_the_window(system):
    data, models = system
    model = models["n4sid"]
    fits, sims = score(model, data, init_window=30)
    y = data.experiments[0].y
    expected = fit(y[30:], sims[0][30:])
    assert list(fits.values()) == pytest.approx(list(expected))
    result = compare([model], data, init_window=30)
    row = result["models"][0]
    assert result["init_window"] == 30
    assert list(row["rmse"].values()) == pytest.approx(list(rmse(y[30:], sims[0][30:])))
    # a window that leaves nothing to score, and an empty window, are refused
    with pytest.raises(DataError, match="leaves no sample"):
        score(model, data, init_window=len(y))
    with pytest.raises(DataError, match="positive number of samples"):
        simulate(model, data.experiments[0].u, y=y, init_window=0)


def test_cli_compare_init_window_prints_rmse_in_units(tmp_path, system, capsys):
    data, models = system
    csv = tmp_path / "d.csv"
    e = data.experiments[0]
    header = "t,u1 [N],u2 [N],y1 [rad],y2 [rad]"
    rows = np.column_stack([e.t, e.u, e.y])
    np.savetxt(csv, rows, delimiter=",", header=header, comments="")
    model_file = tmp_path / "m.json"
    model = models["n4sid"]
    tk.schema.Model(
        **{
            **model.__dict__,
            "inputs": (tk.schema.Signal("u1", "N"), tk.schema.Signal("u2", "N")),
            "outputs": (tk.schema.Signal("y1", "rad"), tk.schema.Signal("y2", "rad")),
        }
    ).save(model_file)
    out_json = tmp_path / "r.json"
    args = ["compare", str(csv), str(model_file), "--init-window", "50", "--json", str(out_json)]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "initial state from the first 50 samples" in text and "RMSE" in text and "rad" in text
    saved = json.loads(out_json.read_text())
    assert saved["init_window"] == 50 and set(saved["models"][0]["rmse"]) == {"y1", "y2"}
    bad = ["compare", str(csv), str(model_file), "--init-window", "5000", "--k", "2"]
    assert main(bad) == 2
    err = capsys.readouterr().err
    assert "leaves nothing to score" in err and "not to --k" in err
