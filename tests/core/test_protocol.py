"""Tests of the data-collection protocols (spec §12)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from tendonkit.errors import OptionError
from tendonkit.robot import RobotParameters
from tendonkit.robot.kinematics import commanded_tensions, inverse_kinematics
from tendonkit.robot.protocol import PHASES, circles, kinematic_controller, petal, pseudo_random

ROBOT = RobotParameters()


@pytest.fixture(scope="module")
def paper_circles():
    return circles()


def test_circle_protocol_structure(paper_circles):
    prot = paper_circles
    assert prot.radii == pytest.approx(np.arange(1, 13) * 0.01)
    # 12 circles × (2 ramps of 2 s, 2 laps, 1 s rest); lap period max(4 s, 2πr / 2.5 cm/s).
    periods = np.maximum(4.0, 2 * np.pi * np.arange(1, 13) / 2.5)
    expected = sum(2 * round(2 / 0.03) + round(1 / 0.03) + round(2 * p / 0.03) for p in periods)
    assert prot.n_samples == expected
    assert prot.duration == pytest.approx(455.0, abs=0.5)
    np.testing.assert_allclose(np.diff(prot.t), 0.03)
    assert set(np.unique(prot.segment)) == set(range(12))
    assert set(np.unique(prot.phase)) == set(range(len(PHASES)))


def test_circle_reference_radius_speed_and_direction(paper_circles):
    prot = paper_circles
    for i, r in enumerate(prot.radii):
        m = prot.mask(i, "main")
        xy = prot.ee_ref[m, :2]
        # The constant-ratio IK is exact to ~1e-12 m, so the reference lies on the circle.
        np.testing.assert_allclose(np.hypot(*xy.T), r, atol=1e-10)
        angle = np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))
        assert np.all(np.diff(angle) > 0)  # counter-clockwise
        speed = np.hypot(*np.diff(xy, axis=0).T).mean() / 0.03
        assert speed == pytest.approx(min(0.025, 2 * np.pi * r / 4.0), rel=1e-3)


def test_circle_commands_span_and_pair_sums(paper_circles):
    u = paper_circles.u
    # Spec §12: the commands span 26–184 N and each pair sum stays 2P.
    assert u.min() == pytest.approx(26.0, abs=1.0) and u.max() == pytest.approx(184.0, abs=1.0)
    np.testing.assert_allclose(u[:, 0] + u[:, 2], 2 * ROBOT.P_nom, atol=1e-9)
    np.testing.assert_allclose(u[:, 1] + u[:, 3], 2 * ROBOT.P_nom, atol=1e-9)
    # Starts and ends at rest at the pretension.
    np.testing.assert_allclose(u[0], ROBOT.P_nom)
    np.testing.assert_allclose(u[-1], ROBOT.P_nom)


def test_clockwise_and_arbitrary_radii():
    prot = circles(radii=[0.015, 0.065, 0.115], clockwise=True, laps=1)
    assert prot.radii == (0.015, 0.065, 0.115)
    xy = prot.ee_ref[prot.mask(1, "main"), :2]
    assert np.all(np.diff(np.unwrap(np.arctan2(xy[:, 1], xy[:, 0]))) < 0)
    np.testing.assert_allclose(np.hypot(*xy.T), 0.065, atol=1e-10)


def test_circle_options_are_validated_together():
    with pytest.raises(OptionError) as err:
        circles(radii=[0.3], laps=-1, h=0.0)
    assert len(err.value.problems) == 3


def test_kinematic_controller_is_consistent():
    xy = np.array([[0.03, -0.02], [0.0, 0.1]])
    q_ref, ee_ref, u = kinematic_controller(xy, 90.0)
    np.testing.assert_allclose(ee_ref[:, :2], xy, atol=1e-12)
    np.testing.assert_allclose(u, commanded_tensions(inverse_kinematics(xy), 90.0))
    assert q_ref.shape == (2, 6)


def test_pseudo_random_is_seeded():
    a = pseudo_random(60.0, seed=3)
    b = pseudo_random(60.0, seed=3)
    c = pseudo_random(60.0, seed=4)
    np.testing.assert_array_equal(a.u, b.u)
    assert not np.allclose(a.u, c.u)
    assert a.n_samples == 2000


def test_pseudo_random_ranges_and_dither():
    prot = pseudo_random(240.0, seed=7)
    radius = np.hypot(*prot.ee_ref[:, :2].T)
    assert radius.max() <= 0.12 + 1e-9 and radius.max() > 0.08
    assert prot.pretension.min() >= 70.0 and prot.pretension.max() <= 130.0
    assert prot.pretension.max() - prot.pretension.min() > 30.0  # it does drift
    assert prot.u.min() >= 20.0 and prot.u.max() <= 190.0
    # Dither = commands minus the smooth controller output, where nothing was clipped.
    _, _, smooth = kinematic_controller(prot.ee_ref[:, :2], prot.pretension, clip=False)
    dither = prot.u - smooth
    free = np.all((prot.u > 20.0) & (prot.u < 190.0), axis=1)
    d = dither[free]
    # White σ = 8 N through a 2nd-order 3 Hz Butterworth at 33.3 Hz leaves σ = 8·‖impulse‖₂
    # ≈ 3.5 N; ±10 % covers the estimate from ~8000 correlated samples and the clipped rows.
    b, a = scipy.signal.butter(2, 3.0, fs=1 / 0.03)
    impulse = scipy.signal.lfilter(b, a, np.r_[1.0, np.zeros(400)])
    expected = 8.0 * np.sqrt(np.sum(impulse**2))
    assert d.std(axis=0) == pytest.approx(np.full(4, expected), rel=0.1)
    corr = np.corrcoef(d.T)
    assert np.abs(corr[np.triu_indices(4, 1)]).max() < 0.1  # independent per tendon


def test_pseudo_random_validation():
    with pytest.raises(OptionError) as err:
        pseudo_random(10.0, seed=-1, pretension_range=(10.0, 300.0), move_s=(0.0, 1.0))
    assert len(err.value.problems) == 3


def test_petal_reference():
    prot = petal(3, 0.09)
    main = prot.mask(phase="main")
    xy = prot.ee_ref[main, :2]
    theta = np.arctan2(xy[:, 1], xy[:, 0])
    r = np.hypot(*xy.T)
    # On the rose |r| = A |cos(3θ)| (polar angle folds sign), to IK precision.
    np.testing.assert_allclose(r, 0.09 * np.abs(np.cos(3 * theta)), atol=1e-9)
    np.testing.assert_allclose(xy[0], [0.09, 0.0], atol=1e-12)
    speed = np.hypot(*np.diff(xy, axis=0).T).mean() / prot.h
    assert speed == pytest.approx(0.025, rel=0.01)
    np.testing.assert_allclose(prot.ee_ref[-1, :2], 0.0, atol=1e-12)
    even = petal(2, 0.08, laps=1)
    assert even.info["period"] > 0
    with pytest.raises(OptionError):
        petal(0, 0.5)
