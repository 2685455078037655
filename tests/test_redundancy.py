"""Any serial arm end to end: what a task tracks (pose or position), secondary objectives in
the null space of a redundant arm (the 7-joint example keeps its carrier stiller), position
limits, and prismatic joints against Pinocchio's planner loop and the replay."""

import dataclasses
import math

import numpy as np
import pytest
from pinocchio_oracle import build_pinocchio_model, pinocchio_plan
from robots import random_robot

from engine import (
    CartesianTask,
    State,
    generalized_jacobian,
    make_inverse,
    make_secondary,
    plan,
    plan_batch,
    replay,
    urdf_robot,
)
from engine.errors import ParameterError
from engine.kernels import redundancy as redundancy_kernels
from engine.kinematics import as_state, forward_kinematics
from engine.spatial import exp_so3

ARM7_Q0 = np.radians([0.0, 40.0, 0.0, 80.0, 0.0, 50.0, 0.0])


def _arm7_task(tracks="pose", **options):
    model = urdf_robot("arm7")
    fk = forward_kinematics(model, as_state(model, ARM7_Q0))
    settings = {"duration": 20.0, "ramp_time": 2.0, "dt": 0.25, "joint_speed_limit": math.radians(6.0), "tracks": tracks}
    return CartesianTask.from_q0(
        model,
        ARM7_Q0,
        fk.ee_position + np.array([-0.2, 0.3, 0.1]),
        exp_so3(np.array([0.0, 0.3, 0.2])) @ fk.ee_attitude,
        **{**settings, **options},
    )


@pytest.fixture(scope="module")
def arm7():
    return urdf_robot("arm7")


@pytest.fixture(scope="module")
def arm3():
    return urdf_robot("arm3")


def test_min_base_rotation_keeps_the_carrier_stiller(arm7, capsys):
    """The 7-joint arm on its spacecraft follows the same line with and without the secondary
    objective: with it, the carrier turns less (its largest and its final attitude change),
    while the end-effector errors stay within the same (sub-millimetre) tolerance and the joints
    within 6 deg/s; the replay confirms the carrier's motion."""
    task = _arm7_task()
    inverse = make_inverse("adaptive", lambda_max=0.05, epsilon=0.05)
    plain = plan(arm7, task, inverse, feedback_gain=1.0)
    still = plan(arm7, task, inverse, feedback_gain=1.0, secondary=make_secondary("min_base_rotation", 0.5))
    for r in (plain, still):
        assert r.success, r.message
        assert r.metrics.position_error_max < 1e-3 and r.metrics.attitude_error_max < math.radians(0.1)
        check = replay(arm7, r)
        assert check.success and check.base_attitude_gap_max < 1e-8
    a, b = plain.metrics, still.metrics
    assert b.base_rotation_max < 0.8 * a.base_rotation_max
    assert b.base_rotation_final < 0.8 * a.base_rotation_final
    with capsys.disabled():
        print(
            f"\narm7 line, carrier attitude change max/final: without {math.degrees(a.base_rotation_max):.3f}/"
            f"{math.degrees(a.base_rotation_final):.3f} deg, with min_base_rotation (gain 0.5) "
            f"{math.degrees(b.base_rotation_max):.3f}/{math.degrees(b.base_rotation_final):.3f} deg; "
            f"end-effector error max {a.position_error_max * 1e3:.3f} vs {b.position_error_max * 1e3:.3f} mm"
        )
    # The base rotation metric is the angle of the stored base attitudes.
    angles = [np.arccos(np.clip((np.trace(A) - 1.0) / 2.0, -1.0, 1.0)) for A in still.base_attitude]
    assert b.base_rotation_max == pytest.approx(max(angles), abs=1e-7)


def test_min_base_rotation_is_the_least_squares_choice(arm7, rng):
    """One step of the kernel: the end-effector velocity is unchanged, the null-space motion is
    the damped least-squares one, and it removes all but a few per cent of the carrier angular
    velocity that any null-space motion can remove (the exact minimiser from numpy's pinv)."""
    for _ in range(10):
        q = ARM7_Q0 + rng.normal(size=7) * 0.2
        g = generalized_jacobian(arm7, State(q))
        J, Omega = g.J_g, np.ascontiguousarray(g.base_velocity_map[3:])
        V = np.linalg.svd(J)[2][:6].T.copy()
        qd_p = rng.normal(size=7) * 0.05
        qd = qd_p.copy()
        work = (np.empty((3, 7)), np.empty((3, 6)), np.empty(6), np.empty(7), np.empty((3, 3)), np.empty(3), np.empty(3))
        redundancy_kernels.null_space_step(redundancy_kernels.MIN_BASE_ROTATION, 1.0, V, Omega, q, q, qd, work)
        np.testing.assert_allclose(J @ qd, J @ qd_p, atol=1e-12)
        P = Omega @ (np.eye(7) - V @ V.T)
        w = Omega @ qd_p
        delta = redundancy_kernels.NULL_SPACE_DAMPING
        np.testing.assert_allclose(qd, qd_p - P.T @ np.linalg.solve(P @ P.T + delta**2 * np.eye(3), w), atol=1e-14)
        exact = w - P @ (np.linalg.pinv(P, rtol=1e-10) @ w)  # the smallest carrier rate any null-space motion gives
        ours = Omega @ qd
        assert np.linalg.norm(ours) ** 2 <= np.linalg.norm(exact) ** 2 + 0.05 * (
            np.linalg.norm(w) ** 2 - np.linalg.norm(exact) ** 2
        )


def test_joint_centering_pulls_towards_the_middle(arm7):
    """The null-space pull towards the middle of the limits moves the joints closer to it than
    the plain plan ends, along the same end-effector path."""
    start = ARM7_Q0.copy()
    start[2] = math.radians(120.0)  # upper-arm roll far from the middle of its range
    model = arm7
    fk = forward_kinematics(model, as_state(model, start))
    task = CartesianTask.from_q0(
        model,
        start,
        fk.ee_position + np.array([0.05, 0.05, 0.0]),
        fk.ee_attitude,
        duration=10.0,
        ramp_time=1.0,
        dt=0.25,
        joint_speed_limit=math.radians(20.0),
    )
    inverse = make_inverse("dls", **{"lambda": 0.01})
    plain = plan(model, task, inverse, feedback_gain=1.0)
    centred = plan(model, task, inverse, feedback_gain=1.0, secondary=make_secondary("joint_centering", 0.2))
    assert plain.success and centred.success, centred.message
    # The distance to the middle of the ranges (all 0 here), 1/2 |q - q_c|^2, falls further.
    spread = [0.5 * float(np.sum(r.q[-1] ** 2)) for r in (plain, centred)]
    assert spread[1] < spread[0] - 0.2
    assert centred.metrics.position_error_max < 1e-3


def test_a_pose_task_needs_six_joints(arm3):
    q0 = np.array([0.0, 0.3, 0.2])
    fk = forward_kinematics(arm3, as_state(arm3, q0))
    task = CartesianTask.from_q0(arm3, q0, fk.ee_position, fk.ee_attitude)
    with pytest.raises(ParameterError, match="tracks: a pose task needs at least 6 joints; this robot has 3"):
        plan(arm3, task, make_inverse("dls"))
    with pytest.raises(ParameterError, match="secondary: a secondary objective needs a redundant arm"):
        plan(*_six_joint_task(), make_inverse("dls"), secondary=make_secondary("joint_centering"))


def _six_joint_task():
    model = random_robot(np.random.default_rng(1), 6)
    q0 = np.zeros(6)
    fk = forward_kinematics(model, as_state(model, q0))
    return model, CartesianTask.from_q0(model, q0, fk.ee_position, fk.ee_attitude)


def test_secondary_gains_are_checked():
    with pytest.raises(ParameterError, match=r"secondary\.gain"):
        make_secondary("min_base_rotation", 1.5)
    with pytest.raises(ParameterError, match=r"secondary\.gain"):
        make_secondary("joint_centering", -1.0)
    with pytest.raises(ParameterError, match=r"secondary\.objective"):
        make_secondary("stillness")


def test_position_task_on_the_three_joint_arm(arm3):
    """A position task on the 3-joint arm (revolute, revolute, prismatic): every method follows
    it; the 3x3 position Jacobian is square, so its determinant is reported; the replay agrees."""
    q0 = np.array([0.0, math.radians(20.0), 0.2])
    fk = forward_kinematics(arm3, as_state(arm3, q0))
    task = CartesianTask.from_q0(
        arm3,
        q0,
        fk.ee_position + np.array([-0.1, 0.3, 0.1]),
        fk.ee_attitude,
        duration=20.0,
        ramp_time=2.0,
        dt=0.25,
        tracks="position",
        linear_joint_speed_limit=0.05,
    )
    for name in ("inverse", "dls", "adaptive", "wdls", "sdls", "svf"):
        r = plan(arm3, task, make_inverse(name), feedback_gain=0.5)
        assert r.success, (name, r.message)
        assert r.singular_values.shape == (task.n_steps + 1, 3) and np.all(np.isfinite(r.det_J_g))
        assert 0.0 < r.metrics.max_linear_joint_speed <= 0.05 and r.metrics.max_linear_joint_speed_joint == 2
    J = generalized_jacobian(arm3, State(r.q[10])).J_g[:3]
    assert abs(r.det_J_g[10]) == pytest.approx(abs(np.linalg.det(J)), rel=1e-9)
    assert replay(arm3, r).plan_gap_position_max < 1e-9
    # The attitude is reported but neither tracked nor part of B.
    assert r.metrics.attitude_error_final > math.radians(5.0)
    assert r.metrics.objective_b == pytest.approx(0.5 * r.metrics.position_error_max)
    # A linear speed limit the plan breaks fails it.
    slow = plan(arm3, dataclasses.replace(task, linear_joint_speed_limit=0.001), make_inverse("dls"), feedback_gain=0.5)
    assert not slow.success and "linear joint speed limit broken" in slow.message and math.isinf(slow.metrics.objective_b)


def test_leaving_a_position_limit_fails_the_plan(arm3):
    q0 = np.array([0.0, math.radians(20.0), 0.45])  # the boom ends at 0.5 m
    fk = forward_kinematics(arm3, as_state(arm3, q0))
    outward = fk.ee_position + 0.2 * (fk.ee_position - forward_kinematics(arm3, as_state(arm3, q0 * [1, 1, 0])).ee_position)
    task = CartesianTask.from_q0(arm3, q0, outward, fk.ee_attitude, duration=10.0, ramp_time=1.0, dt=0.25, tracks="position")
    r = plan(arm3, task, make_inverse("dls", **{"lambda": 0.01}), feedback_gain=0.5)
    assert not r.success and not r.metrics.position_limits_respected
    assert r.metrics.position_limit_joint == 2
    assert "joint 3 (boom_extension) left its position limits [0 m, 0.5 m] at t = " in r.message
    k = round(r.metrics.time_position_limit_left / task.dt)
    assert r.q[k, 2] > 0.5 >= r.q[k - 1, 2]
    assert r.metrics.position_limit_excess == pytest.approx(r.q[:, 2].max() - 0.5)
    assert math.isinf(r.metrics.objective_b)
    batch = plan_batch(arm3, task, "dls", {"lambda": [0.01]}, feedback_gain=0.5)
    assert not batch.metrics.position_limits_respected[0] and math.isinf(batch.metrics.objective_b[0])
    # A start outside the limits is refused.
    with pytest.raises(ParameterError, match=r"q0\[2\]: 0.6 m is outside the limits of joint 3"):
        plan(arm3, dataclasses.replace(task, q0=np.array([0.0, 0.3, 0.6])), make_inverse("dls"))


def test_prismatic_plans_match_pinocchios_planner_loop(rng):
    """Random robots with prismatic joints: the compiled planner against the planner loop
    written with Pinocchio's own functions (frame Jacobian, centroidal map, the Magnus base
    step), on slow tasks (no sub-steps)."""
    done = 0
    while done < 4:
        model = random_robot(rng, int(rng.integers(6, 9)), prismatic=0.5)
        if not model.prismatic.any():
            continue
        q0 = np.where(model.prismatic, rng.uniform(-0.2, 0.2, model.n_joints), rng.uniform(-2.0, 2.0, model.n_joints))
        fk = forward_kinematics(model, as_state(model, q0))
        task = CartesianTask.from_q0(
            model,
            q0,
            fk.ee_position + rng.normal(size=3) * 0.05,
            exp_so3(rng.normal(size=3) * 0.05) @ fk.ee_attitude,
            duration=4.0,
            ramp_time=1.0,
            dt=0.1,
        )
        ours = plan(model, task, make_inverse("adaptive", lambda_max=0.05, epsilon=0.05))
        if np.abs(ours.qd).max() * task.dt > 0.05:  # keep to one base sub-step, like the Pinocchio loop
            continue
        pm, fid = build_pinocchio_model(model)
        theirs = pinocchio_plan(pm, fid, q0, task.samples.twists, task.dt, 0.05, 0.05)
        np.testing.assert_allclose(ours.q, theirs, atol=1e-10)
        done += 1
