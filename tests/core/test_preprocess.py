"""Zero-phase low-pass filtering and the paper's two readings of its cut-off."""

from __future__ import annotations

import numpy as np
import pytest

from tendonkit.dataset import Dataset
from tendonkit.errors import OptionError
from tendonkit.preprocess import lowpass, paper_cutoff_hz, paper_lowpass


def _data(freqs, n=20000, dt=0.03):
    t = dt * np.arange(n)
    y = sum(np.sin(2 * np.pi * f * t) for f in freqs)
    u = np.cos(2 * np.pi * 0.1 * t)
    return Dataset.from_arrays(u, y, dt), t


def test_paper_cutoffs_under_both_conventions():
    assert paper_cutoff_hz(0.03, "literal") == pytest.approx(0.001 / (2 * np.pi * 0.03))
    assert paper_cutoff_hz(0.03, "matlab") == pytest.approx(0.001 / 0.06)
    with pytest.raises(OptionError):
        paper_cutoff_hz(0.03, "other")


def test_lowpass_is_zero_phase_and_removes_the_fast_part():
    ds, t = _data([0.05, 5.0])
    out = lowpass(ds, 1.0)
    slow = np.sin(2 * np.pi * 0.05 * t)
    mid = slice(2000, -2000)  # away from the ends, where forward-backward filtering settles
    np.testing.assert_allclose(out.y[mid, 0], slow[mid], atol=2e-3)  # no lag, no 5 Hz left
    np.testing.assert_array_equal(out.u, ds.u)  # only the outputs by default
    assert not np.array_equal(out.y, ds.y)  # a new dataset; the input is untouched
    assert (
        np.abs(ds.y[:, 0] - (np.sin(2 * np.pi * 0.05 * t) + np.sin(2 * np.pi * 5 * t))).max()
        < 1e-12
    )


def test_paper_filter_removes_even_the_slow_circles():
    """A 10 s circle (0.1 Hz) is far above either reading of the paper's cut-off."""
    ds, _ = _data([0.1])
    for convention in ("literal", "matlab"):
        out = paper_lowpass(ds, convention)
        assert np.std(out.y[2000:-2000]) < 0.05 * np.std(ds.y)


def test_bad_arguments_are_listed():
    ds, _ = _data([0.1], n=200)
    with pytest.raises(OptionError) as info:
        lowpass(ds, 100.0, order=0, signals=["nope"])
    assert len(info.value.problems) == 3
