"""Conformance checks every identifier (built-in or third-party) must pass.

Use them like scikit-learn's ``check_estimator``: run everything at once with
:func:`check_identifier`, or parametrize a pytest test over :func:`identifier_checks` so each
check is reported on its own::

    import pytest
    from tendonkit.testing import identifier_checks

    @pytest.mark.parametrize("check", identifier_checks(), ids=lambda c: c.__name__)
    def test_my_identifier(check):
        check(MyIdentifier())

Each check raises :class:`AssertionError` with an explanation when the identifier breaks the
contract.  The checks use a small, known, well-excited 2-input 2-output system.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from .compare import compare
from .dataset import Dataset
from .errors import DataError, TendonkitError
from .metrics import fit
from .predict import predict
from .schema import Model
from .simulate import simulate
from .testsystems import random_state_space, simulate_truth

#: Minimum validation fit (percent) on the easy conformance system; the truth scores ~99.
MIN_FIT = 50.0

Check = Callable[[Any], None]


@functools.cache
def conformance_data(seed: int = 7) -> tuple[Dataset, Dataset]:
    """Training and validation data of a 2-in, 2-out, order-4 system with 1 % output noise."""

    truth = random_state_space(4, 2, 2, seed=seed, dt=0.05)
    train, _ = simulate_truth(truth, 1500, noise=0.01, seed=seed + 1)
    valid, _ = simulate_truth(truth, 600, noise=0.01, seed=seed + 2)
    return train, valid


def _snapshot(ds: Dataset) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    return [(e.t.copy(), e.u.copy(), e.y.copy()) for e in ds.experiments]


def check_has_metadata(identifier: Any) -> None:
    """The options object is a frozen dataclass with a lowercase ``name`` and a ``description``."""
    cls = type(identifier)
    assert dataclasses.is_dataclass(cls), f"{cls.__name__} must be a dataclass"
    assert cls.__dataclass_params__.frozen, f"{cls.__name__} must be frozen"  # type: ignore[attr-defined]
    name = getattr(identifier, "name", "")
    assert isinstance(name, str) and name and name == name.lower(), f"bad name {name!r}"
    assert getattr(identifier, "description", ""), f"{name} needs a one-line description"


def check_returns_model(identifier: Any) -> None:
    """``identify`` returns a :class:`Model` with the dataset's signals, dt and provenance."""
    train, _ = conformance_data()
    model = identifier.identify(train)
    assert isinstance(model, Model), f"identify returned {type(model).__name__}, not Model"
    assert tuple(model.input_names) == train.inputs, "model inputs differ from the data's"
    assert tuple(model.output_names) == train.outputs, "model outputs differ from the data's"
    assert abs(model.dt - train.dt) < 1e-12, f"dt {model.dt} != data dt {train.dt}"
    assert model.provenance.identifier == identifier.name, "provenance must name the identifier"
    assert model.provenance.dataset_hash == train.hash(), "provenance must hold the data hash"


def check_json_round_trip(identifier: Any) -> None:
    """Saving and loading the model is exact and the reloaded model simulates identically."""
    train, valid = conformance_data()
    model = identifier.identify(train)
    again = Model.from_json(model.to_json())
    assert again == model, "JSON round trip changed the model"
    e = valid.experiments[0]
    a = simulate(model, e.u, y=e.y)
    b = simulate(again, e.u, y=e.y)
    assert np.array_equal(a, b, equal_nan=True), "reloaded model simulates differently"


def check_deterministic(identifier: Any) -> None:
    """Identifying twice on the same data gives the same model."""
    train, _ = conformance_data()
    a = identifier.identify(train).to_dict()
    b = identifier.identify(train).to_dict()
    assert a == b, "identify is not deterministic (seed every random choice)"


def check_leaves_input_untouched(identifier: Any) -> None:
    """``identify`` does not modify the dataset it is given."""
    train, _ = conformance_data()
    before = _snapshot(train)
    identifier.identify(train)
    for (t, u, y), e in zip(before, train.experiments):
        assert np.array_equal(t, e.t) and np.array_equal(u, e.u) and np.array_equal(y, e.y), (
            "identify modified its input data"
        )


def check_shape_errors(identifier: Any) -> None:
    """Too little data is refused with a tendonkit error, and so are wrongly shaped inputs."""
    train, _ = conformance_data()
    tiny = Dataset.from_arrays(
        train.experiments[0].u[:3],
        train.experiments[0].y[:3],
        train.dt,
        train.inputs,
        train.outputs,
    )
    try:
        identifier.identify(tiny)
    except TendonkitError:
        pass
    else:
        raise AssertionError("identify on 3 samples must raise a TendonkitError (DataError)")
    model = identifier.identify(train)
    try:
        simulate(model, np.zeros((10, len(model.inputs) + 1)))
    except DataError:
        pass
    else:
        raise AssertionError("simulate with the wrong number of inputs must raise DataError")


def check_simulate_and_compare(identifier: Any) -> None:
    """The model simulates and predicts on fresh data, with a validation fit above MIN_FIT."""

    train, valid = conformance_data()
    model = identifier.identify(train)
    e = valid.experiments[0]
    y_sim = simulate(model, e.u, y=e.y)
    assert y_sim.shape == e.y.shape and np.all(np.isfinite(y_sim)), "simulation is not finite"
    f = fit(e.y, y_sim)
    assert np.all(f > MIN_FIT), f"validation fit {f} is below {MIN_FIT} % on an easy system"
    y_pred = predict(model, e.u, e.y, k=1)
    assert np.all(np.isfinite(y_pred)), "1-step prediction is not finite"
    assert np.all(fit(e.y, y_pred) >= f - 1.0), "1-step prediction worse than free run"
    res = compare([model], valid)
    assert abs(res["models"][0]["mean_fit"] - float(np.mean(f))) < 1e-9, "compare disagrees"


def identifier_checks() -> list[Check]:
    """Every conformance check, in order."""
    return [
        check_has_metadata,
        check_returns_model,
        check_json_round_trip,
        check_deterministic,
        check_leaves_input_untouched,
        check_shape_errors,
        check_simulate_and_compare,
    ]


def check_identifier(identifier: Any) -> None:
    """Run every check on ``identifier`` (an options object), raising on the first failure."""
    for check in identifier_checks():
        check(identifier)
