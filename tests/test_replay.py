import dataclasses
import math

import numpy as np
import pytest
from oracle.replay import replay as oracle_replay
from robots import random_robot

from engine import CartesianTask, make_inverse, plan, replay
from engine.jacobian import gjm_batch
from engine.kernels import plan as plan_kernels
from engine.kernels import replay as replay_kernels
from engine.kinematics import as_state, forward_kinematics
from engine.spatial import exp_so3, matrix_to_quaternion, quaternion_to_matrix, rotation_angle


@pytest.fixture(scope="module")
def planned(robot, task):
    return plan(robot, task, make_inverse("adaptive"))


def test_replay_agrees_with_the_plan(robot, planned):
    r = replay(robot, planned)
    assert r.success
    assert r.linear_momentum_residual_max < 1e-8
    assert r.angular_momentum_residual_max < 1e-8
    assert r.com_drift_max < 1e-8
    # The planner integrates the base attitude over each step: its path is the physical one.
    assert r.plan_gap_position_max < 2e-5  # 0.02 mm
    assert r.plan_gap_attitude_max < 1e-6
    assert r.base_attitude_gap_max < 1e-6
    # The achieved path tracks the line exactly as planned.
    assert abs(r.path_position_error_max - planned.metrics.position_error_max) < 2e-5


def test_compiled_replay_matches_the_scipy_replay(robot, task):
    """The compiled DOP853 against ``solve_ivp`` with the numpy right-hand side of the oracle."""
    result = plan(
        robot,
        dataclasses.replace(task, path=dataclasses.replace(task.path, duration=5.0, ramp_time=1.0)),
        make_inverse("dls", **{"lambda": 0.05}),
    )
    ours = replay(robot, result)
    theirs = oracle_replay(robot, result)
    np.testing.assert_allclose(ours.ee_position, theirs.ee_position, atol=1e-10)
    np.testing.assert_allclose(ours.base_attitude, theirs.base_attitude, atol=1e-10)
    np.testing.assert_allclose(ours.base_position, theirs.base_position, atol=1e-10)


def _random_task(rng, robot):
    n = robot.n_joints
    q0 = np.where(robot.prismatic, rng.uniform(-0.3, 0.3, n), rng.uniform(-np.pi, np.pi, n))
    fk = forward_kinematics(robot, as_state(robot, q0))
    return CartesianTask.from_q0(
        robot,
        q0,
        fk.ee_position + rng.normal(size=3) * 0.15,
        exp_so3(rng.normal(size=3) * 0.2) @ fk.ee_attitude,
        duration=10.0,
        ramp_time=1.0,
        dt=float(rng.choice([0.1, 0.25, 0.5])),
        joint_speed_limit=math.radians(30.0),
        tracks="pose" if n >= 6 else "position",
    )


@pytest.mark.parametrize("prismatic", [0.0, 0.4])
def test_planned_path_is_the_physical_one_on_random_robots(rng, prismatic):
    """Random 3- to 7-joint robots (pose tasks from 6 joints, position tasks below; revolute
    joints only, or about 40 % prismatic ones): the planned end-effector path and the replayed
    one agree to 0.5 mm (an explicit Euler step of the base attitude left up to 33 mm here)."""
    gaps = []
    for _ in range(30):
        robot = random_robot(rng, int(rng.integers(3, 8)), prismatic=prismatic)
        result = plan(robot, _random_task(rng, robot), make_inverse("dls", **{"lambda": 0.05}))
        if (
            not result.metrics.finite
            or result.metrics.max_joint_speed_deg_s > 30.0
            or result.metrics.max_linear_joint_speed > 0.5
        ):
            continue
        check = replay(robot, result)
        assert check.success
        gaps.append(check.plan_gap_position_max)
    assert len(gaps) >= 15
    assert max(gaps) < 5e-4


def _exact_step(robot, q, qd, dt, A0):
    """The base attitude after a step of linear joint motion, by the replay's integrator."""
    ys = np.zeros((2, 7))
    ys[0, 3:] = matrix_to_quaternion(A0)
    t = np.array([0.0, dt])
    status, _, _ = replay_kernels.integrate(robot.chain, t, np.stack([q, q + qd * dt]), np.stack([qd, qd]), ys, 1e-13, 1e-15)
    assert status == replay_kernels.OK
    return quaternion_to_matrix(ys[1, 3:])


def test_base_attitude_step_is_fourth_order(robot, rng):
    """The local error of the planner's base-attitude step falls like h^5 (Magnus, 4th order)."""
    q = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])
    qd = rng.normal(size=6)
    qd *= 0.5 / np.abs(qd).max()  # 0.2 rad of travel in the longer step: no sub-steps
    A0 = exp_so3(rng.normal(size=3))
    errors = []
    for h in (0.4, 0.2):
        A_plan = plan_kernels.base_attitude_step(robot.chain, q, qd, h, A0)
        errors.append(float(rotation_angle(A_plan.T @ _exact_step(robot, q, qd, h, A0))))
    assert errors[0] > 1e-12  # well above the reference's own error
    assert errors[0] / errors[1] > 20.0  # 32 for a fifth-order local error
    # An explicit Euler step would be first order: far larger at the same h.
    _, base_map = gjm_batch(robot, q[None], A0[None], np.zeros((1, 3)))
    A_euler = exp_so3(base_map[0, 3:] @ qd * 0.4) @ A0
    assert rotation_angle(A_euler.T @ _exact_step(robot, q, qd, 0.4, A0)) > 100 * errors[0]


def test_replay_of_a_diverged_plan_is_a_failure(robot, planned):
    broken = dataclasses.replace(planned, qd=np.full_like(planned.qd, np.nan))
    r = replay(robot, broken)
    assert not r.success and "not finite" in r.message
