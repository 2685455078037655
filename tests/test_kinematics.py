import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pinocchio_oracle import build_pinocchio_model, pinocchio_configuration, pinocchio_gjm
from robots import random_robot

from engine import State, forward_kinematics
from engine.spatial import (
    exp_so3,
    log_so3,
    matrix_to_quaternion,
    matrix_to_rpy_spacedyn,
    quaternion_to_matrix,
    rotation_angle,
    rpy_spacedyn_to_matrix,
)

Q0 = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])


def _wrapped(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_fk_at_paper_start_pose(robot):
    fk = forward_kinematics(robot, State(Q0))
    np.testing.assert_allclose(fk.ee_position, [1.3717, -0.0763, 0.6415], atol=1e-4)
    angles = matrix_to_rpy_spacedyn(fk.ee_attitude)
    # -3.1416 and +3.1416 are the same angle; compare on the circle.
    assert np.all(np.abs(_wrapped(angles - np.array([-3.1416, 0.0, -2.9671]))) < 1e-4)


@pytest.mark.parametrize("prismatic", [0.0, 0.5])
def test_fk_matches_pinocchio_on_random_robots(rng, prismatic):
    for n in (1, 3, 6, 9):
        model = random_robot(rng, n, prismatic=prismatic)
        pm, fid = build_pinocchio_model(model)
        for _ in range(10):
            q = rng.uniform(-np.pi, np.pi, n)
            R = exp_so3(rng.normal(size=3))
            r = rng.normal(size=3)
            fk = forward_kinematics(model, State(q, r, R))
            _, p_pin, A_pin = pinocchio_gjm(pm, fid, pinocchio_configuration(q, r, R))
            np.testing.assert_allclose(fk.ee_position, p_pin, atol=1e-12)
            np.testing.assert_allclose(fk.ee_attitude, A_pin, atol=1e-12)


def test_state_validation(robot):
    with pytest.raises(ValueError, match="base_attitude"):
        State(Q0, base_attitude=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="q"):
        forward_kinematics(robot, State(Q0[:5]))


vectors = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3)


@settings(max_examples=200, deadline=None)
@given(vectors)
def test_exp_log_round_trip(phi):
    phi = np.array(phi)
    if np.linalg.norm(phi) >= np.pi - 1e-6:
        phi = phi / np.linalg.norm(phi) * (np.pi - 1e-3)
    R = exp_so3(phi)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(log_so3(R), phi, atol=1e-9)
    np.testing.assert_allclose(rotation_angle(R), np.linalg.norm(phi), atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(vectors)
def test_quaternion_and_rpy_round_trip(phi):
    R = exp_so3(np.array(phi))
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-12)
    np.testing.assert_allclose(rpy_spacedyn_to_matrix(matrix_to_rpy_spacedyn(R)), R, atol=1e-9)


def test_rpy_in_gimbal_lock_round_trips():
    """b = +-pi/2, where a and c alone are not defined: the angles found give the matrix back."""
    for b in (math.pi / 2, -math.pi / 2):
        for a, c in ((0.3, -1.1), (2.0, 0.5), (-2.9, 3.0)):
            R = rpy_spacedyn_to_matrix([a, b, c])
            angles = matrix_to_rpy_spacedyn(R)
            assert angles[0] == 0.0 and angles[1] == pytest.approx(b, abs=1e-12)
            np.testing.assert_allclose(rpy_spacedyn_to_matrix(angles), R, atol=1e-12)


def test_small_angles_are_exact():
    phi = np.array([1e-10, -2e-10, 3e-10])
    np.testing.assert_allclose(log_so3(exp_so3(phi)), phi, rtol=1e-6, atol=0)


def test_quaternion_rejects_zero_norm():
    with pytest.raises(ValueError):
        quaternion_to_matrix([0.0, 0.0, 0.0, 0.0])
