"""Tests of the robot parameters (spec §6, §8) and the rolling-joint kinematics (spec §3, §12)."""

from __future__ import annotations

import numpy as np
import pytest

from tendonkit.errors import DataError, OptionError
from tendonkit.robot import PAPER_RATIOS, RobotParameters
from tendonkit.robot.kinematics import (
    commanded_tensions,
    expand_joints,
    forward_kinematics,
    frames,
    gravity_torque,
    inverse_kinematics,
    jacobian,
    link_jacobians,
    mass_matrix,
    ratio_matrix,
    rest_inertia,
    scalar_forward_kinematics,
    static_tension_difference,
)

ROBOT = RobotParameters()


def _random_q(n: int, seed: int, scale: float = 0.5) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-scale, scale, (n, 6))


# --------------------------------------------------------------------------- parameters
def test_calibrated_contact_radii_match_spec_table():
    # Spec §6 lists R and a rounded to 0.1 mm.
    np.testing.assert_allclose(ROBOT.R * 1e3, [30.0, 30.0, 44.7, 45.1, 139.0, 124.6], atol=0.05)
    np.testing.assert_allclose(ROBOT.a_in * 1e3, [26.0, 26.0, 42.2, 42.5, 138.2, 123.7], atol=0.05)


def test_calibration_reproduces_the_ratios_in_single_joint_statics():
    # Spec §8: with the ΔT bending joint 1 to q_cal, joint i settles at ratio_i·q_cal.
    dT, P = ROBOT.calibration_delta_T, ROBOT.P_nom
    for i, ratio in enumerate(PAPER_RATIOS):
        q = ratio * ROBOT.q_cal
        lhs = ROBOT.rho * np.cos(q / 2) * dT
        rhs = P * ROBOT.a_sum[i] * np.sin(q / 2) + ROBOT.k_e * q
        assert lhs == pytest.approx(rhs, rel=1e-12)


def test_stiffness_damping_and_inertia_match_spec():
    # Spec §6, printed to three significant digits (relative rounding <= 1e-3).
    np.testing.assert_allclose(ROBOT.stiffness(), [5.98, 5.98, 9.22, 9.30, 29.2, 26.2], rtol=1e-3)
    np.testing.assert_allclose(
        ROBOT.damping, [0.120, 0.120, 0.184, 0.186, 0.584, 0.524], atol=0.0006
    )
    np.testing.assert_allclose(
        np.diag(rest_inertia(ROBOT)),
        [9.65e-3, 5.97e-3, 3.37e-3, 1.67e-3, 6.7e-4, 1.8e-4],
        rtol=0.015,
    )  # printed to 2-3 significant digits: 1.8e-4 stands for 1.82e-4


def test_tendon_offsets_follow_the_conventions():
    rho = ROBOT.rho
    pan, tilt = ROBOT.d[:, 0], ROBOT.d[:, 1]
    np.testing.assert_allclose(pan, [rho, 0, -rho, 0], atol=1e-15)  # T1 bends pan positive
    np.testing.assert_allclose(tilt, [0, rho, 0, -rho], atol=1e-15)  # T2 bends tilt positive
    # Orthogonal tendons exit at a = R, in-plane ones at sqrt(R² − ρ²).
    assert ROBOT.a[1, 0] == ROBOT.R[0] and ROBOT.a[0, 0] == pytest.approx(ROBOT.a_in[0])


def test_derived_arrays_are_read_only():
    with pytest.raises(ValueError):
        ROBOT.R[0] = 1.0


def test_invalid_robot_parameters_list_every_problem():
    with pytest.raises(OptionError) as err:
        RobotParameters(rho=-1.0, P_nom=0.0, ratios=(1.0, 1.0, 2.0, 0.5, 0.2, 0.2))
    assert len(err.value.problems) == 3


def test_robot_flat_dict_round_trip_and_unknown_names():
    robot = RobotParameters(rho=0.014, ratios=(1, 1, 0.6, 0.6, 0.2, 0.25))
    flat = robot.to_dict()
    assert flat["ratio_6"] == 0.25 and all(isinstance(v, float) for v in flat.values())
    assert RobotParameters.from_dict(flat) == robot
    with pytest.raises(OptionError, match="wheel_radius"):
        RobotParameters.from_dict({"wheel_radius": 1.0})


# --------------------------------------------------------------------------- kinematics
def test_verified_geometry():
    # Spec §3: tip at (0, 0, 0.260) m straight; q1 = +0.2 gives (+51.7, 0, 255.1) mm.
    np.testing.assert_allclose(forward_kinematics(np.zeros(6)), [0, 0, 0.260], atol=1e-15)
    ee = forward_kinematics([0.2, 0, 0, 0, 0, 0]) * 1e3
    np.testing.assert_allclose(ee, [51.7, 0.0, 255.1], atol=0.05)  # spec rounds to 0.1 mm


def test_positive_angles_bend_toward_their_tendons():
    assert forward_kinematics([0, 0.2, 0, 0, 0, 0])[1] > 0.04  # tilt -> +y
    assert forward_kinematics([0, 0, 0, 0, 0.2, 0])[0] > 0  # distal pan -> +x
    mirrored = forward_kinematics([-0.2, 0.1, -0.1, 0.05, -0.02, 0.01])
    plain = forward_kinematics([0.2, 0.1, 0.1, 0.05, 0.02, 0.01])
    np.testing.assert_allclose(mirrored, plain * [-1, 1, 1], atol=1e-15)


def test_rolling_joint_lengthens_chain_by_R_q2_over_4():
    # p_i(q) ≈ R (q³/8 e_bend + q²/4 e_z): the top of link 1 rises by about R q²/4 beyond the
    # rotated pitch.  Checked to third order at q = 0.05 (relative error ~q²).
    q = 0.05
    fr = frames([q, 0, 0, 0, 0, 0])
    rise = fr.bottoms[0, 0, 2]
    assert rise == pytest.approx(ROBOT.R[0] * q**2 / 4, rel=1e-2)


def test_fast_fk_agrees_with_frames():
    q = _random_q(50, 1, 0.7)
    np.testing.assert_allclose(forward_kinematics(q), frames(q).ee, atol=1e-15)


def test_jacobian_matches_finite_differences():
    # Central differences with step 1e-6 have truncation error ~1e-12 and rounding ~1e-10.
    q = _random_q(20, 2)
    eps = 1e-6
    numeric = np.stack(
        [
            (forward_kinematics(q + eps * e) - forward_kinematics(q - eps * e)) / (2 * eps)
            for e in np.eye(6)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(jacobian(q), numeric, atol=1e-8)


def test_single_sample_and_batch_agree():
    # One sample takes the scalar path, ten the vectorised one.
    q = _random_q(10, 3)
    np.testing.assert_allclose(forward_kinematics(q[1]), forward_kinematics(q)[1], atol=1e-15)
    np.testing.assert_allclose(jacobian(q[1]), jacobian(q)[1])


def test_scalar_fk_agrees_with_the_vectorised_fk():
    # Plain floats, same formula: equal to rounding (~1e-17 m) for every geometry.
    q = _random_q(100, 4, 0.7)
    for robot in (ROBOT, RobotParameters(link_pitch=0.05, tool_offset=0.03, R_base=0.025)):
        fk = scalar_forward_kinematics(robot)
        got = np.array([fk(row) for row in q.tolist()])
        np.testing.assert_allclose(got, forward_kinematics(q, robot), rtol=0, atol=1e-15)
        np.testing.assert_array_equal(got[7], forward_kinematics(q[7], robot))  # one sample
    with pytest.raises(ValueError):
        scalar_forward_kinematics()([0.1] * 5)


def test_bad_shapes_raise_data_error():
    with pytest.raises(DataError, match=r"\(n, 6\)"):
        forward_kinematics(np.zeros((4, 5)))


def test_mass_matrix_properties():
    m0 = mass_matrix(np.zeros(6))
    np.testing.assert_allclose(m0, m0.T, atol=1e-18)
    # Block-diagonal at q = 0: pan rows 1, 3, 5 decoupled from tilt rows 2, 4, 6.
    assert np.all(m0[np.ix_([0, 2, 4], [1, 3, 5])] == 0)
    mq = mass_matrix(_random_q(5, 4))
    assert np.all(np.linalg.eigvalsh(mq) > 0)
    np.testing.assert_allclose(rest_inertia(ROBOT), m0)


def test_gravity_torque_is_minus_gradient_of_potential():
    # τ_g = Σ m J_vᵀ g must equal −dV/dq with V = −Σ m g·r (central differences, step 1e-6).
    g = np.array([0.0, -9.81, 0.0])
    masses = np.r_[np.full(6, ROBOT.link_mass), ROBOT.tool_mass]
    q = _random_q(4, 5)

    def potential(qq: np.ndarray) -> np.ndarray:
        return -np.einsum("j,nja,a->n", masses, frames(qq).centres, g)

    eps = 1e-6
    grad = np.stack(
        [(potential(q + eps * e) - potential(q - eps * e)) / (2 * eps) for e in np.eye(6)], -1
    )
    np.testing.assert_allclose(gravity_torque(q, g), -grad, atol=1e-8)
    jv, jw, _ = link_jacobians(q)
    assert jv.shape == (4, 7, 3, 6) and jw.shape == (4, 7, 3, 6)


# --------------------------------------------------------------------------- constant ratios
def test_expand_joints_and_ratio_forms():
    q12 = np.array([[0.1, -0.2], [0.3, 0.0]])
    q = expand_joints(q12)
    np.testing.assert_allclose(q[:, 2], 0.6493 * q12[:, 0])
    np.testing.assert_allclose(q[:, 5], 0.2291 * q12[:, 1])
    np.testing.assert_allclose(expand_joints(q12, PAPER_RATIOS[2:]), q)
    with pytest.raises(OptionError):
        ratio_matrix([1.0, 2.0, 3.0])


def test_inverse_kinematics_round_trip_on_the_12cm_disc():
    # Newton with 8 iterations reaches machine precision (tolerance 1e-12 m = 1 pm).
    rng = np.random.default_rng(6)
    r = 0.12 * np.sqrt(rng.uniform(size=300))
    a = rng.uniform(0, 2 * np.pi, 300)
    xy = np.column_stack([r * np.cos(a), r * np.sin(a)])
    q12 = inverse_kinematics(xy)
    np.testing.assert_allclose(forward_kinematics(expand_joints(q12))[:, :2], xy, atol=1e-12)


def test_12cm_circle_joint_ranges():
    # Spec §3/§14: a 12 cm circle needs |q1| ≈ 0.32 rad and |q2| ≈ 0.39 rad (the plant reaches
    # 0.316 / 0.394; the constant-ratio IK differs from the plant by < 2 mrad).
    a = np.linspace(0, 2 * np.pi, 721)
    q12 = inverse_kinematics(0.12 * np.column_stack([np.cos(a), np.sin(a)]))
    assert np.abs(q12[:, 0]).max() == pytest.approx(0.316, abs=0.003)
    assert np.abs(q12[:, 1]).max() == pytest.approx(0.394, abs=0.003)


def test_static_inverse_and_commands():
    dT = static_tension_difference([ROBOT.q_cal, 0.0], ROBOT.P_nom)
    assert dT[0] == pytest.approx(ROBOT.calibration_delta_T, rel=1e-12)
    assert dT[1] == 0.0
    q12 = np.array([[0.1, -0.15], [0.2, 0.05]])
    P = np.array([90.0, 120.0])
    u = commanded_tensions(q12, P)
    np.testing.assert_allclose(u[:, 0] + u[:, 2], 2 * P)  # each pair sum stays 2P
    np.testing.assert_allclose(u[:, 1] + u[:, 3], 2 * P)
    np.testing.assert_allclose(u[:, 0] - u[:, 2], static_tension_difference(q12, P)[:, 0])
    wide = commanded_tensions([[0.7, 0.0]], 105.0)
    assert wide.max() == ROBOT.T_max and wide.min() == ROBOT.T_min


def test_M0_of_0_1_still_works_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="rest_inertia"):
        m0 = ROBOT.M0
    np.testing.assert_array_equal(m0, rest_inertia(ROBOT))
    with pytest.raises(AttributeError):
        _ = ROBOT.not_an_attribute
