"""The ``bounded`` inverse in the planner's step loop: at every step its joint rates satisfy the
KKT conditions of ``min |J qd - xdot|^2 + lambda^2 |qd|^2`` over the box of the speed limits and
of the position limits one step ahead (checked from the plan's own trace with the GJM of
:func:`engine.generalized_jacobian` in world axes and an explicit ``J^T J``, not the kernel's
SVD), it never exceeds a limit (bitwise), and it is DLS wherever no bound is active."""

import math

import numpy as np
from hypothesis import given, note, settings
from hypothesis import strategies as st
from robots import random_robot_dict

from engine import CartesianTask, RobotModel, State, generalized_jacobian, make_inverse, make_secondary, plan, urdf_robot
from engine.kernels.plan import LIMIT_SHRINK
from engine.kinematics import as_state, forward_kinematics
from engine.spatial import exp_so3, log_so3


def _limited_robot(rng, n, prismatic):
    """A random robot and a start ``q0`` whose joints have position limits a little around it
    (some one-sided, some none)."""
    data = random_robot_dict(rng, n, prismatic)
    slides = np.array([link["joint_type"] == "prismatic" for link in data["links"]])
    q0 = np.where(slides, rng.uniform(-0.05, 0.05, n), rng.uniform(-2.0, 2.0, n))
    for j, link in enumerate(data["links"]):
        below, above = rng.uniform(0.01, 0.3, 2)
        side = rng.integers(0, 4)
        link["limits"] = {
            "lower": None if side == 0 else float(q0[j] - below),
            "upper": None if side == 1 else float(q0[j] + above),
        }
        if side == 3:
            link.pop("limits")
    return RobotModel.from_dict(data), q0


def _task(rng, model, q0, tracks, speed, dt):
    fk = forward_kinematics(model, as_state(model, q0))
    return CartesianTask.from_q0(
        model,
        q0,
        fk.ee_position + rng.normal(size=3) * 0.15,
        exp_so3(rng.normal(size=3) * 0.3) @ fk.ee_attitude,
        duration=2.0,
        ramp_time=0.4,
        dt=dt,
        tracks=tracks,
        joint_speed_limit=speed,
        linear_joint_speed_limit=speed * 0.3,
    )


def _box(model, setup_speed, q, dt):
    """The box of the step from ``q`` (the definition: speed limit first, then the position
    limits one step ahead, shrunk by a few ulps so that ``q + qd dt`` cannot round past them)."""
    lo, hi = -setup_speed.copy(), setup_speed.copy()
    lower, upper = model.lower_limits, model.upper_limits
    with np.errstate(invalid="ignore"):
        lo = np.where(np.isfinite(lower), np.maximum(lo, (lower - q) / dt * LIMIT_SHRINK), lo)
        hi = np.where(np.isfinite(upper), np.minimum(hi, (upper - q) / dt * LIMIT_SHRINK), hi)
    return np.minimum(lo, setup_speed), np.maximum(hi, -setup_speed)


def _commanded(task, result, k, gain):
    """The twist the planner commanded at sample k: the path's mean twist plus the feedback."""
    twist = task.samples.twists[k].copy()
    dp = result.ee_position[k] - result.ee_position_desired[k]
    dphi = log_so3(result.ee_attitude[k] @ result.ee_attitude_desired[k].T)
    return twist - gain * np.concatenate([dp, dphi])


def _kkt_at_every_step(model, task, result, lam, gain, rows, speed):
    """Check the KKT conditions of every step of a bounded plan; return how many bounds were
    active over the plan."""
    active = 0
    for k in range(task.n_steps + 1):
        q, qd = result.q[k], result.qd[k]
        J = generalized_jacobian(model, State(q, result.base_position[k], result.base_attitude[k])).J_g[:rows]
        x = _commanded(task, result, k, gain)[:rows]
        lo, hi = _box(model, speed, q, task.dt)
        assert np.all(lo <= qd) and np.all(qd <= hi)
        grad = J.T @ (J @ qd - x) + lam**2 * qd
        scale = np.abs(J.T @ J).max() * np.abs(qd).max() + np.abs(J.T @ x).max() + lam**2 * np.abs(qd).max() + 1e-300
        tol = 1e-9 * scale
        at_hi, at_lo = qd == hi, qd == lo
        free = ~(at_hi | at_lo)
        where = f"k={k} grad={grad} lo={lo} hi={hi} qd={qd}"
        np.testing.assert_allclose(grad[free], 0.0, atol=tol, err_msg=where)  # stationary in the free joints
        assert np.all(grad[at_hi & ~at_lo] <= tol), where  # pushed up against the upper bound
        assert np.all(grad[at_lo & ~at_hi] >= -tol), where  # pushed down against the lower bound
        active += int(np.sum(~free))
    return active


@settings(max_examples=12, deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from([(3, "position"), (4, "position"), (6, "pose"), (7, "pose")]),
    st.floats(1e-3, 0.2),
    st.sampled_from([0.0, 1.0]),
)
def test_every_step_satisfies_the_kkt_conditions_and_every_limit(seed, shape, lam, gain):
    rng = np.random.default_rng(seed)
    n, tracks = shape
    model, q0 = _limited_robot(rng, n, 0.3 if n >= 4 else 0.0)
    speed_rev = float(rng.uniform(0.05, 0.6))
    task = _task(rng, model, q0, tracks, speed_rev, 0.1)
    result = plan(model, task, make_inverse("bounded", **{"lambda": lam}), feedback_gain=gain)
    rows = 6 if tracks == "pose" else 3
    speed = np.where(model.prismatic, task.linear_joint_speed_limit, task.joint_speed_limit)
    assert result.metrics.finite
    # Never over a limit: speeds and positions, bitwise.
    assert np.all(np.abs(result.qd) <= speed)
    assert np.all(result.q >= model.lower_limits) and np.all(result.q <= model.upper_limits)
    assert result.metrics.joint_speed_limit_respected and result.metrics.position_limits_respected
    active = _kkt_at_every_step(model, task, result, lam, gain, rows, speed)
    note(f"active bounds over the plan: {active}")


def test_bounded_is_dls_where_no_bound_is_active(rng, robot):
    """Generous limits: the bounded plan is the DLS plan bit for bit (the QP is skipped when the
    damped rates are inside the box); on the paper task at 6 deg/s the bounds bind and the two
    differ, and the bounded plan meets 6 deg/s where DLS with the same damping breaks it."""
    q0 = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])
    fk = forward_kinematics(robot, as_state(robot, q0))
    loose = CartesianTask.from_q0(
        robot,
        q0,
        fk.ee_position + [0.05, 0.02, -0.04],
        fk.ee_attitude,
        duration=3.0,
        ramp_time=0.5,
        dt=0.1,
        joint_speed_limit=10.0,
    )
    for lam in (0.01, 0.05):
        bounded = plan(robot, loose, make_inverse("bounded", **{"lambda": lam}), feedback_gain=0.5)
        dls = plan(robot, loose, make_inverse("dls", **{"lambda": lam}), feedback_gain=0.5)
        np.testing.assert_array_equal(bounded.q, dls.q)
        np.testing.assert_array_equal(bounded.qd, dls.qd)
    from engine import paper_task

    task = paper_task(robot)
    bounded = plan(robot, task, make_inverse("bounded", **{"lambda": 0.01}))
    dls = plan(robot, task, make_inverse("dls", **{"lambda": 0.01}))
    assert dls.metrics.max_joint_speed > task.joint_speed_limit  # DLS breaks 6 deg/s ...
    assert np.abs(bounded.qd).max() <= task.joint_speed_limit  # ... the bounded inverse cannot
    assert np.abs(bounded.qd).max() == task.joint_speed_limit  # and it does use the limit
    speed = np.full(robot.n_joints, task.joint_speed_limit)
    assert _kkt_at_every_step(robot, task, bounded, 0.01, 0.0, 6, speed) > 0  # the optimum where bounds bind
    assert np.abs(bounded.q - dls.q).max() > 1e-3


def test_bounded_with_a_secondary_objective_keeps_the_limits():
    """On the 7-joint arm with the carrier-rotation objective: the null-space motion enters the
    QP (the box is shifted by it), so the limits hold with it; with loose limits the plan is
    DLS plus the null-space step, bit for bit."""
    arm = urdf_robot("arm7")
    q0 = np.radians([0.0, 40.0, 0.0, 80.0, 0.0, 50.0, 0.0])
    fk = forward_kinematics(arm, as_state(arm, q0))
    secondary = make_secondary("min_base_rotation", 1.0)
    target = (fk.ee_position + [0.1, 0.15, -0.1], exp_so3(np.array([0.0, 0.0, 0.35])) @ fk.ee_attitude)
    tight = CartesianTask.from_q0(arm, q0, *target, duration=6.0, ramp_time=1.0, dt=0.1, joint_speed_limit=math.radians(4.0))
    loose = CartesianTask.from_q0(arm, q0, *target, duration=6.0, ramp_time=1.0, dt=0.1, joint_speed_limit=10.0)
    free = plan(arm, tight, make_inverse("dls", **{"lambda": 0.02}), feedback_gain=1.0, secondary=secondary)
    held = plan(arm, tight, make_inverse("bounded", **{"lambda": 0.02}), feedback_gain=1.0, secondary=secondary)
    assert free.metrics.max_joint_speed > tight.joint_speed_limit  # the objective's motion breaks the limit
    assert np.abs(held.qd).max() <= tight.joint_speed_limit and held.metrics.finite
    same = plan(arm, loose, make_inverse("bounded", **{"lambda": 0.02}), feedback_gain=1.0, secondary=secondary)
    reference = plan(arm, loose, make_inverse("dls", **{"lambda": 0.02}), feedback_gain=1.0, secondary=secondary)
    np.testing.assert_array_equal(same.qd, reference.qd)
