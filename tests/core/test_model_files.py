"""Model files as a hostile user writes them: one SchemaError naming every problem with its path.

Through the CLI the same messages end with exit status 2 (never a traceback, never a hang).
"""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest

from tendonkit.cli import main
from tendonkit.errors import SchemaError
from tendonkit.schema import Model
from tendonkit.testsystems import random_state_space


def _model() -> dict:
    return random_state_space(2, 1, 1, seed=1).to_dict()


def _arx() -> dict:
    return {
        "schema_version": 1,
        "name": "arx",
        "dt": 0.1,
        "inputs": [{"name": "u", "unit": "N"}],
        "outputs": [{"name": "y", "unit": "m"}],
        "representation": {"kind": "arx", "A": [[[-0.5]]], "B": [[[1.0]]], "nk": [1]},
    }


def _bad(data: dict, *needles: str) -> None:
    with pytest.raises(SchemaError) as info:
        Model.from_json(json.dumps(data))
    for needle in needles:
        assert needle in str(info.value), str(info.value)


def test_a_string_or_a_bool_in_a_matrix_is_named_with_its_path():
    d = _model()
    d["representation"]["A"][0][1] = "0.5"
    d["representation"]["C"][0][0] = True
    _bad(
        d,
        'representation.A[0][1]: expected a number, found "0.5"',
        "representation.C[0][0]: expected a number, found true",
    )


def test_schema_version_true_is_not_1():
    d = _model()
    d["schema_version"] = True
    _bad(d, "schema_version True is not supported")


@pytest.mark.parametrize("field", ["dt", "matrix", "training_fit"])
def test_integers_too_large_for_a_double(field):
    text = json.dumps(_model())
    big = "1" + "0" * 400
    if field == "dt":
        text = text.replace('"dt": 0.03', f'"dt": {big}')
        needle = "dt: expected a positive number"
    elif field == "matrix":
        d = _model()
        d["representation"]["D"] = [[0]]
        text = json.dumps(d).replace('"D": [[0]]', f'"D": [[{big}]]')
        needle = "representation.D[0][0]: expected a number"
    else:
        d = _model()
        d["provenance"]["training_fit"] = {"y1": 0}
        text = json.dumps(d).replace('"y1": 0}', f'"y1": {big}}}')
        needle = "training_fit: expected {output: finite number}"
    with pytest.raises(SchemaError) as info:
        Model.from_json(text)
    assert needle in str(info.value)


def test_kind_and_term_function_of_the_wrong_type():
    d = _model()
    d["representation"]["kind"] = []
    _bad(d, "representation.kind: [] is not one of")
    a = _arx()
    a["representation"]["terms"] = [{"factors": [{"signal": "y", "lag": 1, "fn": ["abs"]}]}]
    a["representation"]["term_coefficients"] = [[0.1]]
    _bad(a, "representation.terms[0].factors[0].fn: ['abs'] is not one of")
    a["representation"]["terms"][0]["factors"][0]["fn"] = {"f": 1}
    _bad(a, "representation.terms[0].factors[0].fn")


def test_huge_delays_and_lags_are_capped_with_the_cap_in_the_message():
    a = _arx()
    a["representation"]["nk"] = [10**12]
    _bad(a, "representation.nk: expected a list of integers from 0 to 100000")
    a = _arx()
    a["input_blocks"] = [{"kind": "delay", "signal": "u", "params": {"samples": 1e9}}]
    _bad(a, "input_blocks[0].params.samples: a delay from 0 to 100000 samples")
    a = _arx()
    a["representation"]["terms"] = [{"factors": [{"signal": "y", "lag": 10**9}]}]
    a["representation"]["term_coefficients"] = [[0.1]]
    _bad(a, "lag: expected an integer from 0 to 100000")


@pytest.mark.parametrize("name", ["y,1", "y\n1", "y 1", 'y"', "1y", "y;z", "q\x00"])
def test_names_that_would_break_a_csv_or_an_fmu(name):
    a = _arx()
    a["outputs"][0]["name"] = name
    _bad(a, "outputs[0].name:", "is not a signal name")


def test_deep_nesting_is_refused_before_parsing():
    text = "[" * 1000 + "]" * 1000
    with pytest.raises(SchemaError, match="nests 1000 levels deep; a model is at most 32"):
        Model.from_json(text)


def test_every_problem_at_once():
    d = _model()
    d["dt"] = -1
    d["representation"]["A"][0][0] = None
    d["inputs"][0]["name"] = "a,b"
    with pytest.raises(SchemaError) as info:
        Model.from_json(json.dumps(d))
    assert len(info.value.problems) == 3, info.value.problems


def test_valid_models_still_round_trip():
    m = random_state_space(3, 2, 2, seed=4)
    assert Model.from_json(m.to_json()) == m
    a = Model.from_json(json.dumps(_arx()))
    np.testing.assert_array_equal(a.representation.A[0], [[-0.5]])


@pytest.mark.parametrize(
    "mutate",
    [
        lambda t: "[" * 1000 + "]" * 1000,
        lambda t: t.replace('"kind": "state_space"', '"kind": []'),
        lambda t: t.replace('"dt": 0.1', '"dt": ' + "9" * 400),
    ],
    ids=["deep", "kind-list", "huge-dt"],
)
def test_the_cli_says_it_in_one_message(tmp_path, capsys, csv_file, mutate):
    bad = tmp_path / "bad.json"
    bad.write_text(mutate(random_state_space(2, 2, 2, seed=3, dt=0.1).to_json()))
    data = csv_file()
    for args in (
        ["simulate", str(bad), str(data), "-o", str(tmp_path / "o.csv")],
        ["compare", str(data), str(bad)],
        ["export", str(bad), "-o", str(tmp_path / "m.fmu")],
        ["mpc", str(bad), "--reference", "petal"],
    ):
        code = main(args)
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err and "bad.json" in err, (args, err)
    assert not (tmp_path / "o.csv").exists() and not (tmp_path / "m.fmu").exists()


def test_a_fifo_as_model_file_is_refused_without_blocking(tmp_path, csv_file, capsys):
    fifo = tmp_path / "model.json"
    os.mkfifo(fifo)
    start = time.monotonic()
    code = main(["simulate", str(fifo), str(csv_file()), "-o", str(tmp_path / "o.csv")])
    assert code == 2 and "FIFO" in capsys.readouterr().err
    assert time.monotonic() - start < 30
