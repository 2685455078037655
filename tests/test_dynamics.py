"""Free-floating inverse dynamics and the executed trajectory against independent truth:
Pinocchio's RNEA and ABA on the equivalent free-flyer model (no gravity), an open-loop forward
simulation, Newton-Euler on the carrier by finite differences, scipy's cubic spline."""

import math

import numpy as np
import pinocchio as pin
import pytest
from pinocchio_oracle import build_pinocchio_model, pinocchio_configuration
from robots import random_robot
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from engine import (
    CartesianTask,
    RobotModel,
    State,
    forward_kinematics,
    make_inverse,
    plan,
    plan_batch,
    replay,
    table1_robot,
    urdf_robot,
)
from engine.dynamics import inverse_dynamics, plan_dynamics
from engine.executed import executed_motion, executed_trajectory, from_plan, replay_executed
from engine.kernels import chain as chain_kernels
from engine.kernels import dynamics as dynamics_kernels
from engine.kernels import replay as replay_kernels
from engine.kinematics import kinematics_batch
from engine.spatial import exp_so3, matrix_to_quaternion, quaternion_to_matrix, rotation_angle

ROBOTS = {
    "table1": lambda rng: table1_robot(),
    "arm7": lambda rng: urdf_robot("arm7"),
    "arm3": lambda rng: urdf_robot("arm3"),
    "random": lambda rng: random_robot(rng, int(rng.integers(3, 13))),
    "random-prismatic": lambda rng: random_robot(rng, int(rng.integers(3, 13)), prismatic=0.5),
}


def _pinocchio(model):
    pm, _ = build_pinocchio_model(model)
    pm.gravity = pin.Motion.Zero()  # a space robot: no gravity
    return pm, pm.createData()


def _random_states(rng, model, count):
    n = model.n_joints
    q = np.where(model.prismatic, rng.uniform(-0.3, 0.3, (count, n)), rng.uniform(-np.pi, np.pi, (count, n)))
    return (
        q,
        rng.normal(size=(count, n)),
        rng.normal(size=(count, n)),
        exp_so3(rng.normal(size=(count, 3))),
        rng.normal(size=(count, 3)),
    )


def _pin_velocity(A0, twist, qd):
    """Pinocchio's free-flyer velocity: the base twist in the base frame, then the joint rates."""
    return np.concatenate([A0.T @ twist[:3], A0.T @ twist[3:], qd])


def _pin_acceleration(A0, twist, acc, qdd):
    """Pinocchio's free-flyer acceleration: the derivative of the base-frame twist, whose linear
    part is the classical acceleration minus ``w x v`` (base frame)."""
    v, w = A0.T @ twist[:3], A0.T @ twist[3:]
    return np.concatenate([A0.T @ acc[:3] - np.cross(w, v), A0.T @ acc[3:], qdd])


@pytest.mark.parametrize("name", list(ROBOTS))
def test_torques_match_pinocchio_rnea(rng, name):
    """With our base acceleration, Pinocchio's RNEA needs no base wrench (to 1e-9 of the forces
    at play) and gives our joint torques; the wrench joint 1 transmits
    (Pinocchio's ``f[2]``; ``f[1]`` is the free flyer's) is minus our mount wrench; the base
    twist carries zero momentum."""
    for _ in range(3 if name.startswith("random") else 1):
        model = ROBOTS[name](rng)
        pm, data = _pinocchio(model)
        q, qd, qdd, A0, pos = _random_states(rng, model, 20)
        ours = inverse_dynamics(model, q, qd, qdd, A0, pos)
        assert ours.success
        for k in range(q.shape[0]):
            config = pinocchio_configuration(q[k], pos[k], A0[k])
            v = _pin_velocity(A0[k], ours.base_twist[k], qd[k])
            a = _pin_acceleration(A0[k], ours.base_twist[k], ours.base_acceleration[k], qdd[k])
            # The scale of the forces at play: the base wrench without our base acceleration.
            scale = np.abs(pin.rnea(pm, data, config, v, np.concatenate([np.zeros(6), qdd[k]]))).max()
            tau = pin.rnea(pm, data, config, v, a)
            np.testing.assert_allclose(tau[:6], 0.0, atol=1e-9 * scale)
            np.testing.assert_allclose(ours.joint_torques[k], tau[6:], rtol=0.0, atol=1e-9 * scale)
            f1 = data.f[2].copy()  # what the base exerts on the arm at joint 1 (Pinocchio's joint 2), in its frame
            pin.forwardKinematics(pm, data, config)  # (rnea does not update oMi)
            frame, base = data.oMi[2], data.oMi[1]
            force = frame.rotation @ f1.linear
            # Our moment is about joint 1's point on the carrier (Pinocchio's frame slides with a
            # prismatic joint's link).
            p1 = base.rotation @ model.base.b + base.translation
            moment = frame.rotation @ f1.angular + np.cross(frame.translation - p1, force)
            np.testing.assert_allclose(ours.mount_force[k], -A0[k].T @ force, atol=1e-9 * scale)
            np.testing.assert_allclose(ours.mount_torque[k], -A0[k].T @ moment, atol=1e-9 * scale)
            assert np.abs(pin.computeCentroidalMomentum(pm, data, config, v).vector).max() < 1e-9 * scale
        assert scale > 1.0  # the states do exercise the dynamics


@pytest.mark.parametrize("name", list(ROBOTS))
def test_aba_with_our_torques_reproduces_the_accelerations(rng, name):
    """Forward dynamics (Pinocchio's ABA) with our torques and no base wrench gives back the
    joint accelerations and our base acceleration."""
    for _ in range(3 if name.startswith("random") else 1):
        model = ROBOTS[name](rng)
        pm, data = _pinocchio(model)
        q, qd, qdd, A0, pos = _random_states(rng, model, 20)
        ours = inverse_dynamics(model, q, qd, qdd, A0, pos)
        for k in range(q.shape[0]):
            config = pinocchio_configuration(q[k], pos[k], A0[k])
            v = _pin_velocity(A0[k], ours.base_twist[k], qd[k])
            ddq = pin.aba(pm, data, config, v, np.concatenate([np.zeros(6), ours.joint_torques[k]]))
            expected = _pin_acceleration(A0[k], ours.base_twist[k], ours.base_acceleration[k], qdd[k])
            np.testing.assert_allclose(ddq, expected, rtol=0.0, atol=1e-9 * np.abs(expected).max())


def _quaternion_rate(quat_xyzw, w):
    """``d/dt`` of Pinocchio's (x, y, z, w) quaternion under the base-frame rate ``w``."""
    x, y, z, s = quat_xyzw
    vec = np.array([x, y, z])
    return 0.5 * np.concatenate([s * w + np.cross(vec, w), [-vec @ w]])


def _smooth_samples(rng, model, count, dt):
    """Joint samples of a smooth, moderately fast motion (~0.3 rad/s, 0.1 m/s)."""
    n = model.n_joints
    t = dt * np.arange(count)
    scale = np.where(model.prismatic, 0.1, 0.3)
    phase = rng.uniform(0, 2 * np.pi, n)
    q0 = np.where(model.prismatic, rng.uniform(-0.2, 0.2, n), rng.uniform(-np.pi, np.pi, n))
    return t, q0 + scale * np.sin(t[:, None] * 1.3 + phase) - scale * np.sin(phase)


@pytest.mark.parametrize("name", ["table1", "arm3"])
def test_open_loop_simulation_follows_the_executed_trajectory(rng, name):
    """Integrate Pinocchio's ABA under our torques as a function of time alone (open loop, no
    feedback), interval by interval (the spline's jerk jumps at the knots), DOP853 at rtol 1e-11:
    the joints follow the executed trajectory to 1e-9 rad (m) over 2 s, and the base the motion
    that :func:`executed_motion` integrates from momentum alone. The bound: without feedback the
    integrator's local errors (rtol 1e-11) accumulate like a double integrator's, to a few 1e-12
    here; torques off by 1e-6 relative leave 3e-7 rad, so 1e-9 separates the two."""
    model = ROBOTS[name](rng)
    pm, data = _pinocchio(model)
    n = model.n_joints
    t, q_samples = _smooth_samples(rng, model, 9, 0.25)
    trajectory = executed_trajectory(t, q_samples, rng.normal(size=n) * 0.1, rng.normal(size=n) * 0.1)
    A0, p0 = exp_so3(rng.normal(size=3)), rng.normal(size=3)
    start = inverse_dynamics(model, trajectory.q[:1], trajectory.qd[:1], trajectory.qdd[:1], A0, p0)

    def torques(time):
        q, qd, qdd = trajectory.at([time])
        return inverse_dynamics(model, q, qd, qdd).joint_torques[0]

    def rhs(time, x):
        config = np.concatenate([x[:3], x[3:7] / np.linalg.norm(x[3:7]), x[7 : 7 + n]])
        v = x[7 + n :]
        R = quaternion_to_matrix(np.concatenate([[x[6]], x[3:6]]) / np.linalg.norm(x[3:7]))
        ddq = pin.aba(pm, data, config, v, np.concatenate([np.zeros(6), torques(time)]))
        return np.concatenate([R @ v[:3], _quaternion_rate(x[3:7], v[3:6]), v[6:], ddq])

    config0 = pinocchio_configuration(trajectory.q[0], p0, A0)
    x = np.concatenate([config0, _pin_velocity(A0, start.base_twist[0], trajectory.qd[0])])
    checks = np.linspace(0.0, t[-1], 33)  # includes the knots
    sim_q, sim_pose = [x[7 : 7 + n].copy()], [x[:7].copy()]
    for k in range(t.shape[0] - 1):
        inside = checks[(checks > t[k]) & (checks <= t[k + 1])]
        assert inside[-1] == t[k + 1]
        sol = solve_ivp(rhs, (t[k], t[k + 1]), x, method="DOP853", rtol=1e-11, atol=1e-12, t_eval=inside)
        assert sol.success
        sim_q.extend(sol.y[7 : 7 + n].T)
        sim_pose.extend(sol.y[:7].T)
        x = sol.y[:, -1]
    sim_q = np.array(sim_q)
    sim_pose = np.array(sim_pose)
    np.testing.assert_allclose(sim_q, trajectory.at(checks)[0], rtol=0.0, atol=1e-9)
    motion = executed_motion(model, trajectory, p0, A0, checks)
    assert motion.success
    np.testing.assert_allclose(sim_pose[:, :3], motion.base_position, rtol=0.0, atol=1e-9)
    sim_A = quaternion_to_matrix(np.concatenate([sim_pose[:, 6:7], sim_pose[:, 3:6]], axis=1))
    assert rotation_angle(np.swapaxes(sim_A, 1, 2) @ motion.base_attitude).max() < 1e-9
    # The motion is not trivial: the joints travel and the base turns.
    assert np.abs(sim_q - sim_q[0]).max() > 0.05
    assert rotation_angle(motion.base_attitude[-1] @ A0.T) > 1e-3


@pytest.mark.parametrize("name", list(ROBOTS))
def test_zero_joint_motion_needs_no_torque(rng, name):
    model = ROBOTS[name](rng)
    q, _, _, A0, pos = _random_states(rng, model, 5)
    zero = np.zeros_like(q)
    still = inverse_dynamics(model, q, zero, zero, A0, pos)
    for field in ("joint_torques", "mount_force", "mount_torque", "base_twist", "base_acceleration"):
        assert np.all(getattr(still, field) == 0.0), field
    # A constant rate alone (no acceleration) does need torques: the test can fail.
    assert np.abs(inverse_dynamics(model, q, np.ones_like(q), zero, A0, pos).joint_torques).max() > 1e-6


@pytest.mark.parametrize("name", ["table1", "random-prismatic"])
def test_dynamics_do_not_depend_on_where_the_system_is(rng, name):
    """No gravity: the torques and the mount wrench (carrier frame) are the same for any base
    pose, and the base twist and acceleration turn with it. Computed in the base frame with the
    system CoM at the origin, as the planner's step loop has the kinematics, through the
    per-sample kernel and preallocated buffers: given the GJM's twist (``base_map @ qd``), and
    finding the zero-momentum twist itself, which must be that twist."""
    model = ROBOTS[name](rng)
    n = model.n_joints
    q, qd, qdd, A0, pos = _random_states(rng, model, 6)
    world = inverse_dynamics(model, q, qd, qdd, A0, pos)
    kin, g, work = chain_kernels.kinematics_buffers(n), chain_kernels.gjm_buffers(n), dynamics_kernels.dynamics_buffers(n)
    tau, force, torque, twist, acc = np.empty(n), np.empty(3), np.empty(3), np.empty(6), np.empty(6)
    for k in range(q.shape[0]):
        chain_kernels.kinematics(model.chain, q[k], np.eye(3), np.zeros(3), True, kin)
        chain_kernels.gjm(model.chain, kin, g)
        twist[:] = g[1] @ qd[k]
        assert dynamics_kernels.inverse_dynamics(model.chain, kin, twist, qd[k], qdd[k], work, tau, force, torque, acc, False)
        found, tau_found, acc_found = np.full(6, np.nan), np.empty(n), np.empty(6)
        assert dynamics_kernels.inverse_dynamics(
            model.chain, kin, found, qd[k], qdd[k], work, tau_found, np.empty(3), np.empty(3), acc_found, True
        )
        np.testing.assert_allclose(found, twist, rtol=0.0, atol=1e-13 * max(1.0, np.abs(twist).max()))
        np.testing.assert_allclose(tau_found, tau, rtol=0.0, atol=1e-12 * np.abs(tau).max())
        np.testing.assert_allclose(acc_found, acc, rtol=0.0, atol=1e-11)
        scale = np.abs(tau).max()
        np.testing.assert_allclose(world.joint_torques[k], tau, rtol=0.0, atol=1e-12 * scale)
        np.testing.assert_allclose(world.mount_force[k], force, rtol=0.0, atol=1e-12 * scale)
        np.testing.assert_allclose(world.mount_torque[k], torque, rtol=0.0, atol=1e-12 * scale)
        np.testing.assert_allclose(world.base_twist[k], np.concatenate([A0[k] @ twist[:3], A0[k] @ twist[3:]]), atol=1e-12)
        np.testing.assert_allclose(world.base_acceleration[k], np.concatenate([A0[k] @ acc[:3], A0[k] @ acc[3:]]), atol=1e-11)


@pytest.mark.parametrize("name", ["table1", "arm3"])
def test_mount_wrench_is_the_rate_of_change_of_the_carriers_momentum(rng, name):
    """Newton-Euler on the carrier alone: the wrench the arm exerts on it is the rate of change
    of its momentum (linear, and angular about the world origin), and the base acceleration is
    the rate of change of the base twist; both by central differences along the integrated
    executed motion (h = 1e-4 s: the O(h^2) error is below 3e-7 of the wrench here, and
    shrinks 100-fold from h = 1e-3 s)."""
    model = ROBOTS[name](rng)
    t, q_samples = _smooth_samples(rng, model, 9, 0.25)
    trajectory = executed_trajectory(t, q_samples)
    A_start, p_start = exp_so3(rng.normal(size=3)), rng.normal(size=3)
    h = 1e-4
    centres = rng.uniform(t[1], t[-2], 6)
    times = np.sort(np.concatenate([centres - h, centres, centres + h]))
    motion = executed_motion(model, trajectory, p_start, A_start, times)
    assert motion.success
    q, qd, qdd = trajectory.at(times)
    dyn = inverse_dynamics(model, q, qd, qdd, motion.base_attitude, motion.base_position)
    m0, I0 = model.base.mass, model.base.inertia
    A0, c0 = motion.base_attitude, motion.base_position
    v0, w0 = dyn.base_twist[:, :3], dyn.base_twist[:, 3:]
    P = m0 * v0
    L = np.einsum("kij,jl,kml,km->ki", A0, I0, A0, w0) + m0 * np.cross(c0, v0)
    p1 = kinematics_batch(model, q, A0, c0).joint_positions[:, 0]
    force_w = np.einsum("kij,kj->ki", A0, dyn.mount_force)
    torque_o = np.einsum("kij,kj->ki", A0, dyn.mount_torque) + np.cross(p1, force_w)
    for i in range(1, times.shape[0], 3):  # times are (centre - h, centre, centre + h)
        dP = (P[i + 1] - P[i - 1]) / (2 * h)
        dL = (L[i + 1] - L[i - 1]) / (2 * h)
        scale = max(np.abs(force_w[i]).max(), np.abs(torque_o[i]).max())
        np.testing.assert_allclose(force_w[i], dP, atol=1e-6 * scale)
        np.testing.assert_allclose(torque_o[i], dL, atol=1e-6 * scale)
        d_twist = (dyn.base_twist[i + 1] - dyn.base_twist[i - 1]) / (2 * h)
        np.testing.assert_allclose(dyn.base_acceleration[i], d_twist, atol=1e-6 * np.abs(d_twist).max())
        assert scale > 1e-3


def test_executed_trajectory_is_the_clamped_spline_through_the_samples(rng):
    """The spline passes through the samples, has the asked end rates, equals scipy's clamped
    cubic spline, and its rate and acceleration are the derivatives of its position (central
    differences) and continuous at the knots."""
    n = 5
    t = np.cumsum(np.concatenate([[0.3], rng.uniform(0.1, 0.5, 12)]))  # uneven steps
    q = np.cumsum(rng.normal(size=(13, n)), axis=0)
    v0, v1 = rng.normal(size=n), rng.normal(size=n)
    trajectory = executed_trajectory(t, q, v0, v1)
    q_at, qd_at, _ = trajectory.at(t)
    np.testing.assert_allclose(q_at, q, rtol=0.0, atol=1e-13 * np.abs(q).max())
    np.testing.assert_allclose(qd_at[[0, -1]], [v0, v1], rtol=0.0, atol=1e-12)
    reference = CubicSpline(t, q, bc_type=((1, v0), (1, v1)))
    times = rng.uniform(t[0], t[-1], 200)
    for nu, ours in enumerate(trajectory.at(times)):
        np.testing.assert_allclose(ours, reference(times, nu), rtol=1e-12, atol=1e-12 * np.abs(reference(times, nu)).max())
    eps = 1e-5
    inner = rng.uniform(t[0] + eps, t[-1] - eps, 50)
    qm, qdm, _ = trajectory.at(inner - eps)
    qp, qdp, _ = trajectory.at(inner + eps)
    _, qd_c, qdd_c = trajectory.at(inner)
    np.testing.assert_allclose((qp - qm) / (2 * eps), qd_c, atol=1e-7 * np.abs(qd_c).max())
    np.testing.assert_allclose((qdp - qdm) / (2 * eps), qdd_c, atol=1e-7 * np.abs(qdd_c).max())
    for nu, values in enumerate(trajectory.at(t[1:-1] - 1e-9)):
        np.testing.assert_allclose(values, trajectory.at(t[1:-1] + 1e-9)[nu], atol=1e-6 * np.abs(values).max())


def test_executed_motion_of_linear_joint_motion_is_the_replay(rng):
    """Samples on a line with the line's rate at both ends: the spline is that line (no
    acceleration), and its integrated motion is the replay of the constant-rate plan; extra
    requested times change nothing."""
    model = table1_robot()
    t = 0.25 * np.arange(9)
    q0, rate = rng.uniform(-np.pi, np.pi, 6), rng.normal(size=6) * 0.2
    q = q0 + t[:, None] * rate
    trajectory = executed_trajectory(t, q, rate, rate)
    np.testing.assert_allclose(trajectory.qdd, 0.0, atol=1e-12)
    A0, p0 = exp_so3(rng.normal(size=3)), rng.normal(size=3)
    ys = np.zeros((t.shape[0], 7))
    ys[0, :3], ys[0, 3:] = p0, matrix_to_quaternion(A0)
    status, _, _ = replay_kernels.integrate(model.chain, t, q, np.broadcast_to(rate, q.shape).copy(), ys, 1e-11, 1e-13)
    assert status == replay_kernels.OK
    motion = executed_motion(model, trajectory, p0, A0)
    np.testing.assert_allclose(motion.base_position, ys[:, :3], atol=1e-10)
    assert rotation_angle(np.swapaxes(quaternion_to_matrix(ys[:, 3:]), 1, 2) @ motion.base_attitude).max() < 1e-10
    finer = executed_motion(model, trajectory, p0, A0, np.linspace(0.0, t[-1], 21))
    np.testing.assert_allclose(finer.ee_position[::5], motion.ee_position[::2], atol=1e-10)


def test_executing_the_paper_plan(robot, task):
    """The executed paper plan: it starts at rest and ends at the plan's last rate, its
    motion conserves momentum, keeps the plan's tracking to O(dt^2) (well under 0.1 mm, where
    the plan's own path error is millimetres) and needs finite torques, largest mid-path."""
    result = plan(robot, task, make_inverse("adaptive", lambda_max=0.040, epsilon=0.37))
    trajectory = from_plan(result)
    np.testing.assert_allclose(trajectory.qd[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(trajectory.qd[-1], result.qd[-1], atol=1e-12)
    executed = replay_executed(robot, result)
    assert executed.success
    assert executed.linear_momentum_residual_max < 1e-10 and executed.angular_momentum_residual_max < 1e-10
    assert executed.com_drift_max < 1e-10
    assert 0.0 < executed.plan_gap_position_max < 1e-4
    assert executed.plan_gap_attitude_max < 1e-4
    assert abs(executed.path_position_error_max - replay(robot, result).path_position_error_max) < 1e-4
    dynamics = plan_dynamics(robot, result)
    assert dynamics.success and dynamics.joint_torques.shape == result.q.shape
    assert np.all(dynamics.peak_torques > 0.0)
    peak = np.abs(dynamics.joint_torques).max(axis=1).argmax()
    assert 0 < peak < result.t.shape[0] - 1


def _open_loop(model, trajectory, p0, A0, times, rtol=1e-11):
    """Pinocchio's ABA integrated under the torques of ``trajectory`` (our RNEA along it, a
    function of time alone: no feedback), interval by interval between its knots (the jerk jumps
    there), from its first state with the base twist of zero momentum; the joints and the base
    pose (position, quaternion x y z w) at ``times`` (the knots included)."""
    pm, data = _pinocchio(model)
    n = model.n_joints
    t = trajectory.t
    start = inverse_dynamics(model, trajectory.q[:1], trajectory.qd[:1], trajectory.qdd[:1], A0, p0)

    def rhs(time, x):
        config = np.concatenate([x[:3], x[3:7] / np.linalg.norm(x[3:7]), x[7 : 7 + n]])
        v = x[7 + n :]
        R = quaternion_to_matrix(np.concatenate([[x[6]], x[3:6]]) / np.linalg.norm(x[3:7]))
        q, qd, qdd = trajectory.at([time])
        tau = inverse_dynamics(model, q, qd, qdd).joint_torques[0]
        ddq = pin.aba(pm, data, config, v, np.concatenate([np.zeros(6), tau]))
        return np.concatenate([R @ v[:3], _quaternion_rate(x[3:7], v[3:6]), v[6:], ddq])

    x = np.concatenate(
        [pinocchio_configuration(trajectory.q[0], p0, A0), _pin_velocity(A0, start.base_twist[0], trajectory.qd[0])]
    )
    sim_q, sim_pose = [x[7 : 7 + n].copy()], [x[:7].copy()]
    for k in range(t.shape[0] - 1):
        inside = times[(times > t[k]) & (times <= t[k + 1])]
        sol = solve_ivp(rhs, (t[k], t[k + 1]), x, method="DOP853", rtol=rtol, atol=1e-12, t_eval=inside)
        assert sol.success
        sim_q.extend(sol.y[7 : 7 + n].T)
        sim_pose.extend(sol.y[:7].T)
        x = sol.y[:, -1]
    return np.array(sim_q), np.array(sim_pose)


def test_the_paper_plan_torques_drive_an_independent_simulator_along_the_plan(robot, task):
    """The issue's "done when": the paper plan (the README's tuned adaptive damping) returns
    torques that an independent simulator reproduces. Pinocchio's forward dynamics (ABA, its own
    free-flyer model) driven open loop by our torques over the whole 15 s follows the executed
    trajectory to 1e-10 rad and the base the motion that momentum conservation gives, so the
    joints pass through every planned sample; and the torques the planner returned at the
    samples (computed in the compiled step loop, base frame) are those of the RNEA along the
    executed trajectory (world frame, the plan's base poses). The margin: torques off by 1e-6
    relative would leave about 1e-5 rad after 15 s (accelerations of 0.1 rad/s^2)."""
    result = plan(robot, task, make_inverse("adaptive", lambda_max=0.040, epsilon=0.37))
    assert result.success and result.metrics.joint_torque_limit_respected
    trajectory = from_plan(result)
    along = plan_dynamics(robot, result)
    scale = np.abs(along.joint_torques).max()
    np.testing.assert_allclose(result.joint_torques, along.joint_torques, rtol=0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(result.joint_accelerations, trajectory.qdd, rtol=0.0, atol=1e-14)
    np.testing.assert_allclose(result.mount_force, along.mount_force, rtol=0.0, atol=1e-12 * scale)
    np.testing.assert_allclose(result.mount_torque, along.mount_torque, rtol=0.0, atol=1e-12 * scale)
    assert result.metrics.max_joint_torque == np.abs(result.joint_torques).max()
    A0, p0 = result.base_attitude[0], result.base_position[0]
    sim_q, sim_pose = _open_loop(robot, trajectory, p0, A0, result.t)
    np.testing.assert_allclose(sim_q, result.q, rtol=0.0, atol=1e-10)
    sim_A = quaternion_to_matrix(np.concatenate([sim_pose[:, 6:7], sim_pose[:, 3:6]], axis=1))
    motion = executed_motion(robot, trajectory, p0, A0, result.t)
    np.testing.assert_allclose(sim_pose[:, :3], motion.base_position, rtol=0.0, atol=1e-10)
    assert rotation_angle(np.swapaxes(sim_A, 1, 2) @ motion.base_attitude).max() < 1e-10
    # ... and that base is the plan's to the executed trajectory's tracking change (micrometres)
    assert rotation_angle(np.swapaxes(sim_A, 1, 2) @ result.base_attitude).max() < 1e-5
    print(
        f"\npaper plan under Pinocchio's ABA: joints within {np.abs(sim_q - result.q).max():.1e} rad of the plan "
        f"over 15 s; peak torques {np.array2string(np.abs(result.joint_torques).max(axis=0), precision=3)} N m"
    )


@pytest.mark.parametrize("name", ["arm7", "arm3", "random-prismatic"])
def test_every_plan_carries_the_dynamics_of_its_executed_trajectory(rng, name):
    """The compiled step loop's torques, forces and mount wrench (base frame, after the loop)
    against the RNEA along :func:`from_plan` (world frame, the plan's base poses) for revolute
    and prismatic joints and position tasks; the metrics' peaks (the kept plan's and a
    metrics-only evaluation's) are the arrays' maxima by joint type."""
    model = ROBOTS[name](rng)
    n = model.n_joints
    tracks = "pose" if n >= 6 else "position"
    q0 = np.where(model.prismatic, rng.uniform(0.05, 0.2, n), rng.uniform(-1.5, 1.5, n))
    if model.limited:
        q0 = np.clip(q0, model.lower_limits + 0.05, model.upper_limits - 0.05)
    fk = forward_kinematics(model, State(q0))
    task = CartesianTask.from_q0(
        model, q0, fk.ee_position + [0.03, -0.02, 0.02], fk.ee_attitude, duration=3.0, ramp_time=0.5, dt=0.1, tracks=tracks
    )
    result = plan(model, task, make_inverse("dls", **{"lambda": 0.05}), feedback_gain=1.0)
    assert result.metrics.finite
    along = plan_dynamics(model, result)
    scale = np.abs(along.joint_torques).max()
    assert scale > 0.0
    np.testing.assert_allclose(result.joint_torques, along.joint_torques, rtol=0.0, atol=1e-11 * scale)
    np.testing.assert_allclose(result.mount_force, along.mount_force, rtol=0.0, atol=1e-11 * scale)
    np.testing.assert_allclose(result.mount_torque, along.mount_torque, rtol=0.0, atol=1e-11 * scale)
    effort = np.abs(result.joint_torques)
    revolute, prismatic = effort[:, ~model.prismatic], effort[:, model.prismatic]
    m = result.metrics
    assert m.max_joint_torque == (revolute.max() if revolute.size else 0.0)
    assert m.max_joint_force == (prismatic.max() if prismatic.size else 0.0)
    batch = plan_batch(model, task, "dls", {"lambda": [0.05]}, feedback_gain=1.0).metrics
    assert batch.dynamics_computed[0] == float(model.effort_limited)
    if model.effort_limited:  # the URDF examples carry <limit effort>: metrics-only plans check them
        assert batch.max_joint_torque[0] == m.max_joint_torque and batch.max_joint_force[0] == m.max_joint_force


def test_a_plan_over_a_torque_limit_fails_naming_the_joint_the_time_and_the_value(robot, task):
    """The paper plan needs 1.29 N m at the shoulder (joint 2) as the arm stops; with that
    joint's limit at 1 N m the plan fails, the verdict names the joint, the first time over and
    the largest torque against the limit, B is infinite (P_l), and a metrics-only evaluation
    (GA, landscapes) finds the same."""
    inverse = make_inverse("adaptive", lambda_max=0.040, epsilon=0.37)
    data = robot.to_dict()
    data["links"][1]["torque_limit_n_m"] = 1.0
    weak = RobotModel.from_dict(data)
    result = plan(weak, task, inverse)
    tau = np.abs(result.joint_torques[:, 1])
    first = result.t[np.argmax(tau > 1.0)]
    assert not result.success and not result.metrics.joint_torque_limit_respected
    assert math.isinf(result.metrics.objective_b)
    assert result.metrics.torque_limit_joint == 1 and result.metrics.time_torque_limit_exceeded == first
    assert (
        f"joint torque limit broken: joint 2 (joint2) needs up to {tau.max():.4g} N m (limit 1 N m), "
        f"first over it at t = {first:g} s" in result.message
    )
    assert f"first failed at t = {first:g} s (joint 2 needed" in result.message
    batch = plan_batch(weak, task, "adaptive", {"lambda_max": [0.040], "epsilon": [0.37]}).metrics
    assert not batch.joint_torque_limit_respected[0] and math.isinf(batch.objective_b[0])
    assert batch.torque_limit_peak[0] == tau.max()
    assert plan(robot, task, inverse).success  # the Table-1 defaults (5 N m there) hold
