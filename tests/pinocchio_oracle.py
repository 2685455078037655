"""Independent oracle: the same robot as a Pinocchio free-flyer model (test-only dependency)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from engine.model import RobotModel


def build_pinocchio_model(model: RobotModel) -> tuple[pin.Model, int]:
    """Pinocchio model of ``model`` and the id of its end-effector frame.

    Joint i's frame sits at joint i with the attitude of link i, so each joint placement
    is a pure translation ``a_{i-1} + b_{i-1}`` (``b_0`` for joint 1) and each body's CoM
    lever is ``a_i``.
    """
    pm = pin.Model()
    parent = pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    pm.appendBodyToJoint(parent, pin.Inertia(model.base.mass, np.zeros(3), np.array(model.base.inertia)), pin.SE3.Identity())
    offset = np.array(model.base.b)
    for link in model.links:
        jm = pin.JointModelRevoluteUnaligned(np.array(link.joint_axis))
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
