"""The model schema: exact JSON round trip, strict loading, python-control export."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tendonkit.errors import SchemaError
from tendonkit.schema import ARX, Block, Model, Signal, SparseMap, StateSpace
from tendonkit.terms import Factor, Term

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def models(draw):
    nu = draw(st.integers(1, 3))
    ny = draw(st.integers(1, 3))
    kind = draw(st.sampled_from(["state_space", "arx", "sparse_map"]))
    inputs = tuple(Signal(f"u{i}", "N") for i in range(nu))
    outputs = tuple(Signal(f"y{i}", "rad") for i in range(ny))
    states: tuple[Signal, ...] = ()
    if kind == "state_space":
        n = draw(st.integers(1, 4))
        rep = StateSpace(
            A=draw(arrays(float, (n, n), elements=finite)),
            B=draw(arrays(float, (n, nu), elements=finite)),
            C=draw(arrays(float, (ny, n), elements=finite)),
            D=draw(arrays(float, (ny, nu), elements=finite)),
            x0=draw(st.none() | arrays(float, (n,), elements=finite)),
        )
    elif kind == "arx":
        na, nb = draw(st.integers(0, 3)), draw(st.integers(1, 3))
        rep = ARX(
            A=tuple(draw(arrays(float, (ny, ny), elements=finite)) for _ in range(na)),
            B=tuple(draw(arrays(float, (ny, nu), elements=finite)) for _ in range(nb)),
            nk=tuple(draw(st.integers(0, 3)) for _ in range(nu)),
            offset=draw(st.none() | arrays(float, (ny,), elements=finite)),
        )
    else:
        states = tuple(Signal(f"x{i}") for i in range(ny))
        names = [s.name for s in states] + [s.name for s in inputs]
        factor = st.builds(
            Factor,
            signal=st.sampled_from(names),
            fn=st.sampled_from(["pow", "sin", "tanh", "dead_zone", "sign"]),
            power=st.integers(1, 3),
            lag=st.integers(0, 2),
            scale=finite,
            offset=finite,
            param=finite,
        )
        terms = tuple(
            Term(tuple(draw(st.lists(factor, max_size=3)))) for _ in range(draw(st.integers(1, 4)))
        )
        rep = SparseMap(
            terms=terms,
            coefficients=draw(arrays(float, (len(terms), ny), elements=finite)),
            output_states=tuple(range(ny)),
        )
    return Model(
        name=draw(st.text(max_size=10)),
        dt=draw(st.floats(1e-6, 1e3)),
        inputs=inputs,
        outputs=outputs,
        states=states,
        representation=rep,
        input_blocks=(Block("delay", "u0", {"samples": 2.0}),) if draw(st.booleans()) else (),
    )


@settings(max_examples=150, deadline=None)
@given(models())
def test_json_round_trip_is_exact(model):
    text = model.to_json()
    again = Model.from_json(text)
    assert again == model
    assert again.to_json() == text  # byte-identical second round


def _ss_model() -> Model:
    return Model(
        "m",
        0.03,
        (Signal("F1", "N"),),
        (Signal("q1", "rad"),),
        StateSpace(np.array([[0.9]]), np.array([[0.1]]), np.array([[1.0]]), np.array([[0.0]])),
    )


def test_unknown_schema_version_is_refused_with_its_number():
    data = _ss_model().to_dict()
    data["schema_version"] = 99
    with pytest.raises(SchemaError, match="schema_version 99 is not supported"):
        Model.from_dict(data)


def test_malformed_file_lists_every_problem():
    data = _ss_model().to_dict()
    data["dt"] = -1
    data["representation"]["A"] = [[1.0, 2.0]]  # wrong shape
    data["inputs"] = [{"name": 3}]
    data["surprise"] = 1
    with pytest.raises(SchemaError) as info:
        Model.from_dict(data, "bad.json")
    text = str(info.value)
    assert "dt: expected a positive number" in text
    assert "inputs[0]" in text
    assert "unknown top-level keys ['surprise']" in text
    assert len(info.value.problems) >= 3


def test_shape_mismatch_is_named():
    data = _ss_model().to_dict()
    data["representation"]["B"] = [[0.1, 0.2]]
    with pytest.raises(SchemaError, match=r"B must have shape \(1, 1\), found \(1, 2\)"):
        Model.from_dict(data)


def test_loading_never_evaluates_code(tmp_path):
    """Strings that look like code are names, and unknown names are refused, never run."""
    model = Model(
        "m",
        0.1,
        (Signal("u"),),
        (Signal("y"),),
        SparseMap((Term((Factor("x"),)),), np.array([[0.5]]), (0,)),
        states=(Signal("x"),),
    )
    data = model.to_dict()
    # the payload names an absolute path, so the check below sees it wherever the process runs
    pwned = tmp_path / "PWNED"
    data["representation"]["terms"][0]["factors"][0]["signal"] = (
        f"__import__('pathlib').Path({str(pwned)!r}).touch()"
    )
    data["representation"]["terms"][0]["factors"][0]["fn"] = "eval"
    path = tmp_path / "evil.json"
    path.write_text(json.dumps(data))
    with pytest.raises(SchemaError, match="'eval' is not one of"):
        Model.load(path)
    assert not pwned.exists()


def test_nan_in_json_is_refused():
    text = _ss_model().to_json().replace("0.9", "NaN")
    with pytest.raises(SchemaError, match="NaN"):
        Model.from_json(text)


def test_missing_file_message():
    with pytest.raises(SchemaError, match="does not exist"):
        Model.load("/nonexistent/model.json")


def test_to_control_of_arx_matches_simulation():
    import control

    rng = np.random.default_rng(0)
    rep = ARX(
        A=(np.array([[-0.5, 0.1], [0.0, -0.3]]), np.array([[0.06, 0.0], [0.02, 0.01]])),
        B=(rng.normal(size=(2, 3)), rng.normal(size=(2, 3))),
        nk=(1, 0, 2),
    )
    m = Model("arx", 0.1, tuple(Signal(f"u{i}") for i in range(3)), (Signal("a"), Signal("b")), rep)
    sys = m.to_control()
    assert isinstance(sys, control.StateSpace) and sys.dt == 0.1
    u = rng.normal(size=(200, 3))
    from tendonkit.simulate import simulate

    y_arx = simulate(m, u, initial="zero")
    resp = control.forced_response(sys, U=u.T)
    np.testing.assert_allclose(resp.outputs.T, y_arx, atol=1e-10)


def test_to_control_refuses_nonlinear():
    m = Model(
        "s",
        0.1,
        (Signal("u"),),
        (Signal("y"),),
        SparseMap((Term((Factor("x", fn="sin"),)),), np.array([[1.0]]), (0,)),
        states=(Signal("x"),),
    )
    with pytest.raises(SchemaError, match="nonlinear"):
        m.to_control()


def test_inconsistent_model_is_refused_at_construction():
    with pytest.raises(SchemaError) as info:
        Model(
            "m",
            0.0,
            (Signal("u"),),
            (Signal("u"),),
            StateSpace(np.eye(2), np.ones((2, 1)), np.ones((1, 3)), np.zeros((1, 1))),
        )
    text = str(info.value)
    assert (
        "dt must be a positive" in text
        and "repeated: ['u']" in text
        and "C must have shape" in text
    )
