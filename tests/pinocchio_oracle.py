"""Independent oracle: the same robot as a Pinocchio free-flyer model (test-only dependency)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from engine.model import RobotModel


def build_pinocchio_model(model: RobotModel) -> tuple[pin.Model, int]:
    """Pinocchio model of ``model`` and the id of its end-effector frame.

    Joint i's frame sits at joint i with the attitude of link i, so each joint placement
    is a pure translation ``a_{i-1} + b_{i-1}`` (``b_0`` for joint 1) and each body's CoM
    lever is ``a_i`` (a prismatic joint's frame slides along its axis with the body).
    """
    pm = pin.Model()
    parent = pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    pm.appendBodyToJoint(parent, pin.Inertia(model.base.mass, np.zeros(3), np.array(model.base.inertia)), pin.SE3.Identity())
    offset = np.array(model.base.b)
    for link in model.links:
        axis = np.array(link.joint_axis)
        jm = pin.JointModelPrismaticUnaligned(axis) if link.prismatic else pin.JointModelRevoluteUnaligned(axis)
        parent = pm.addJoint(parent, jm, pin.SE3(np.eye(3), offset), link.name)
        pm.appendBodyToJoint(parent, pin.Inertia(link.mass, np.array(link.a), np.array(link.inertia)), pin.SE3.Identity())
        offset = np.array(link.a) + np.array(link.b)
    frame_id = pm.addFrame(pin.Frame("ee", parent, 0, pin.SE3(np.array(model.C_e), offset), pin.FrameType.OP_FRAME))
    return pm, frame_id


def pinocchio_configuration(q: np.ndarray, base_position: np.ndarray, base_attitude: np.ndarray) -> np.ndarray:
    quat = pin.Quaternion(np.array(base_attitude))
    quat.normalize()
    return np.concatenate([base_position, quat.coeffs(), q])  # coeffs are (x, y, z, w)


def pinocchio_gjm(pm: pin.Model, frame_id: int, q_pin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(J_g, ee_position, ee_attitude)`` from Pinocchio: ``J_m - J_b A_b^-1 A_m`` with the
    centroidal momentum matrix ``A = [A_b, A_m]`` (zero momentum)."""
    data = pm.createData()
    pin.forwardKinematics(pm, data, q_pin)
    pin.updateFramePlacements(pm, data)
    J = pin.computeFrameJacobian(pm, data, q_pin, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    Ag = pin.computeCentroidalMap(pm, data, q_pin)
    J_g = J[:, 6:] - J[:, :6] @ np.linalg.solve(Ag[:, :6], Ag[:, 6:])
    placement = data.oMf[frame_id]
    return J_g, placement.translation.copy(), placement.rotation.copy()


def adaptive_joint_rates(J_g: np.ndarray, xdot: np.ndarray, lam_max: float, epsilon: float) -> np.ndarray:
    """Eq. 16 written out with ``np.linalg.svd`` (no engine code)."""
    U, s, Vt = np.linalg.svd(J_g, full_matrices=False)
    lam = np.where(s < epsilon, 0.5 * lam_max * (1.0 + np.cos(np.pi * s / epsilon)), 0.0)
    return Vt.T @ ((s / (s * s + lam * lam)) * (U.T @ xdot))


def pinocchio_plan(pm: pin.Model, frame_id: int, q0: np.ndarray, twists: np.ndarray, dt: float, lam_max: float, epsilon: float):
    """The planner loop written with Pinocchio's own functions, reusing no engine code: the GJM
    from the frame Jacobian and the centroidal momentum matrix, eq. 16 on ``np.linalg.svd``, the
    joints by ``q += qd dt`` and the base by ``pin.integrate`` with the fourth-order Magnus
    rotation over the step (the base's local angular velocity at the start, middle and end of the
    joint line, from the centroidal map; ``Omega = dt/6 (w_0 + 4 w_m + w_1) + dt^2/12 w_0 x w_1``),
    the base position then shifted so the centre of mass stays put.

    ``twists (N+1, 6)`` are the commanded world twists. Returns the joint angles ``(N+1, n)``.
    """
    data = pm.createData()
    n = q0.shape[0]
    q_pin = pinocchio_configuration(q0, np.zeros(3), np.eye(3))
    com0 = pin.centerOfMass(pm, data, q_pin).copy()

    def base_map(config: np.ndarray) -> np.ndarray:
        Ag = pin.computeCentroidalMap(pm, data, config)
        return -np.linalg.solve(Ag[:, :6], Ag[:, 6:])  # joint rates -> base twist, base frame

    qs = np.empty((twists.shape[0], n))
    bm = base_map(q_pin)
    for k in range(twists.shape[0]):
        J = pin.computeFrameJacobian(pm, data, q_pin, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        J_g = J[:, 6:] + J[:, :6] @ bm  # the free flyer's velocity is in the base frame, like bm
        qd = adaptive_joint_rates(J_g, twists[k], lam_max, epsilon)
        qs[k] = q_pin[7:]
        if k == twists.shape[0] - 1:
            break
        w0 = bm[3:] @ qd
        mid = q_pin.copy()
        mid[7:] += qd * (0.5 * dt)
        wm = base_map(mid)[3:] @ qd
        end = q_pin.copy()
        end[7:] += qd * dt
        bm = base_map(end)
        w1 = bm[3:] @ qd
        omega = dt / 6.0 * (w0 + 4.0 * wm + w1) + dt * dt / 12.0 * np.cross(w0, w1)
        v = np.concatenate([np.zeros(3), omega / dt, qd])
        q_pin = pin.integrate(pm, q_pin, v * dt)
        q_pin[:3] += com0 - pin.centerOfMass(pm, data, q_pin)
    return qs
