"""The linear rows of the real-benchmark table (issue 17), a smaller run of bench_real.py.

The protocol (splits, initialisation windows, Bouc–Wen's periodic steady state) is the
benchmark script's own ``linear_cases()`` and ``rmse()``, imported from benchmarks/bench_real.py so
that the test and the published table cannot drift apart.  Every model is identified with
**default options**, except that on the three long records (Silverbox, Wiener–Hammerstein,
Bouc–Wen) ``pem`` is given the order its default selection chooses there (2, 7 and 3, no
integrator: benchmarks/README.md; delays and feedthrough are still estimated), which skips
up to 100 s of cross-validation per record on CI; the selection itself runs here on EMPS,
the tanks and CED, and on all six in the benchmark script.  The coupled drives are identified
one model per record, as the split pairs each record's training and test parts
(``bench_real.linear_cases``; the joint model on both training parts is reported beside them
in the benchmark's README).

Rows where tendonkit's best linear model does not yet reach the published best linear result
are strict expected failures with the measured gap: they fail the suite the day they pass, so
the table gets updated.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

import tendonkit as tk

pytestmark = [pytest.mark.slow, pytest.mark.first, pytest.mark.usefixtures("real_data")]

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_real.py"


@functools.cache
def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_real", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@functools.cache
def _case(dataset: str) -> tuple[Any, dict[str, tuple[Any, int | str]]]:
    for name, train, tests in _bench().linear_cases():
        if name == dataset:
            return train, {t: (data, init) for t, data, init in tests}
    raise KeyError(dataset)


def _unmet(reason: str) -> Any:
    return pytest.mark.xfail(strict=True, reason=reason)


ROWS = [
    # dataset, test, identifier, options, published best linear (in the data's unit)
    pytest.param("EMPS", "EMPS", "pem", {}, 5.53e-3, id="EMPS-pem"),  # selection included
    # the coupled drives: one model per record, each record's own training part (the split's
    # pairs; bench_real.linear_cases)
    pytest.param(
        "Coupled electric drives (low)", "CED low", "n4sid", {}, 0.224, id="CED-low-n4sid"
    ),
    pytest.param("Coupled electric drives (high)", "CED high", "pem", {}, 0.331, id="CED-high-pem"),
    pytest.param(
        "Bouc-Wen",
        "Bouc-Wen multisine",
        "pem",
        {"order": 3, "integrator": False},
        1.5e-4,
        id="BoucWen-pem",
    ),
    pytest.param(
        "Wiener-Hammerstein",
        "Wiener-Hammerstein",
        "pem",
        {"order": 7, "integrator": False},
        43.4e-3,
        id="WH-pem",
    ),
    pytest.param(
        "Silverbox",
        "Silverbox multisine",
        "pem",
        {"order": 2, "integrator": False},
        6.95e-3,
        marks=_unmet("6.960 mV against 6.95 (0.14 % short)"),
        id="Silverbox-pem",
    ),
    pytest.param(
        "Cascaded tanks",
        "Cascaded tanks",
        "pem",
        {},
        0.588,
        marks=_unmet("0.602 V against 0.588 (2.3 % short; the overflow clips the data)"),
        id="tanks-pem",
    ),
]


@pytest.mark.parametrize(("dataset", "test", "method", "options", "published"), ROWS)
def test_best_linear_model_meets_the_published_linear_result(
    dataset: str, test: str, method: str, options: dict[str, Any], published: float
) -> None:
    train, tests = _case(dataset)
    data, init = tests[test]
    model = tk.identify(train, method, **options)
    rmse = _bench().rmse(model, data, init)
    print(f"{test}: {method} RMSE {rmse:.4g} (published best linear {published:.4g})")
    assert rmse <= published
