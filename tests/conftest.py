"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tendonkit.dataset import Dataset, write_csv
from tendonkit.testsystems import random_state_space, simulate_truth

SHARED = Path(__file__).resolve().parents[2] / "shared"
REAL_DATA = SHARED / "data" / "real"


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
