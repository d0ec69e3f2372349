"""Shared fixtures."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tendonkit.dataset import Dataset, write_csv
from tendonkit.testsystems import random_state_space, simulate_truth

#: The workplace's shared folder beside the repository (CI provides it); TENDONKIT_SHARED
#: points elsewhere.  Tests that need it fail, never skip, when it is missing.
SHARED = Path(os.environ.get("TENDONKIT_SHARED", Path(__file__).resolve().parents[2] / "shared"))
REAL_DATA = SHARED / "data" / "real"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests that read the real benchmark data are marked ``real_data`` (``make check`` skips them).

    Tests marked ``first`` (the longest ones) are moved to the front: xdist hands tests out in
    collection order, and a two-minute test handed out last would finish the run alone.
    """
    for item in items:
        if "real_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.real_data)
    items.sort(key=lambda item: item.get_closest_marker("first") is None)  # stable


@pytest.fixture(scope="session", autouse=True)
def _temporary_files_stay_in_basetemp(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """Temporary files made by the tests and the commands they run go under pytest's base
    folder, which pytest rotates: fmpy unpacks every FMU it opens into a temporary folder, and
    a test that opens an FMU by hand does not delete it (a run left about 150 unpacked FMUs,
    binaries included, in the system's temporary folder)."""
    import tempfile

    folder = str(tmp_path_factory.mktemp("tempfile"))
    before, env = tempfile.tempdir, os.environ.get("TMPDIR")
    tempfile.tempdir = os.environ["TMPDIR"] = folder  # the commands tests run inherit it
    yield
    tempfile.tempdir = before
    if env is None:
        os.environ.pop("TMPDIR", None)
    else:
        os.environ["TMPDIR"] = env


@pytest.fixture
def real_data() -> Path:
    """The real benchmark data folder; a clear failure when it is not there."""
    if not REAL_DATA.is_dir():
        pytest.fail(
            f"The real benchmark data are not at {REAL_DATA}: clone the repository beside the "
            "shared/ folder (as CI does) or set TENDONKIT_SHARED to its path."
        )
    return REAL_DATA


@pytest.fixture(scope="session")
def truth8():
    """The 4-input, 2-output, order-8 test system."""
    return random_state_space(8, 4, 2, seed=0)


@pytest.fixture(scope="session")
def small_data():
    """Noisy train/validation data from a 2-in 2-out order-4 system."""
    truth = random_state_space(4, 2, 2, seed=3, dt=0.05)
    train, _ = simulate_truth(truth, 2000, noise=0.01, seed=4)
    valid, _ = simulate_truth(truth, 800, noise=0.01, seed=5)
    return truth, train, valid


@pytest.fixture
def csv_file(tmp_path, small_data):
    """The small training data written as CSV with columns t, u1, u2, y1, y2, extra."""

    def make(ds: Dataset = small_data[1], name: str = "data.csv") -> Path:
        e = ds.experiments[0]
        cols = {"t": e.t}
        cols.update({n: e.u[:, j] for j, n in enumerate(ds.inputs)})
        cols.update({n: e.y[:, j] for j, n in enumerate(ds.outputs)})
        cols["extra"] = np.arange(len(e.t), dtype=float)
        return write_csv(tmp_path / name, cols)

    return make
