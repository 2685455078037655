"""Random URDF serial arms for tests, and the Pinocchio free-flyer model built from a URDF text."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from robots import random_inertia

from engine import RobotModel, State


def _vec(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _inertial(rng: np.random.Generator, mass: float) -> str:
    inertia = np.array(random_inertia(rng, float(rng.uniform(0.2, 5.0))))
    xyz = rng.uniform(-0.3, 0.3, 3)
    rpy = rng.uniform(-math.pi, math.pi, 3)  # a rotated inertial frame
    keys = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}
    attrs = " ".join(f'{k}="{float(inertia[i, j])!r}"' for k, (i, j) in keys.items())
    return f'<inertial><origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/><mass value="{mass!r}"/><inertia {attrs}/></inertial>'


def random_urdf(rng: np.random.Generator, n_joints: int, prismatic: float = 0.3) -> str:
    """A URDF serial arm: a massive root link, a massless mounting frame and a massive flange on
    fixed joints, then ``n_joints`` moving joints (revolute with limits or continuous, or
    prismatic with probability ``prismatic``; urdfdom, Pinocchio's reader, refuses revolute
    joints without a ``<limit>``), random joint origins
    and unit axes, fixed links with mass hanging off some links, and a massless tool frame
    ``tool0`` as the only leaf."""
    parts = [f'<robot name="random{n_joints}">']
    parts.append(f'<link name="base">{_inertial(rng, float(rng.uniform(100.0, 600.0)))}</link>')
    parts.append('<link name="mount"/>')  # a massless frame
    parts.append(
        f'<joint name="mount_joint" type="fixed"><parent link="base"/><child link="mount"/>'
        f'<origin xyz="{_vec(rng.uniform(-0.8, 0.8, 3))}" rpy="{_vec(rng.uniform(-3, 3, 3))}"/></joint>'
    )
    parent = "mount"
    for i in range(n_joints):
        link = f"link{i + 1}"
        parts.append(f'<link name="{link}">{_inertial(rng, float(rng.uniform(0.5, 12.0)))}</link>')
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        kind = "prismatic" if rng.uniform() < prismatic else str(rng.choice(["revolute", "continuous"]))
        limit = ""
        if kind == "prismatic":
            limit = '<limit lower="-0.5" upper="0.5" effort="10" velocity="0.2"/>'
        elif kind == "revolute":
            limit = '<limit lower="-3.0" upper="3.0" effort="10" velocity="1"/>'
        parts.append(
            f'<joint name="joint{i + 1}" type="{kind}"><parent link="{parent}"/><child link="{link}"/>'
            f'<origin xyz="{_vec(rng.uniform(-0.4, 0.4, 3))}" rpy="{_vec(rng.uniform(-3, 3, 3))}"/>'
            f'<axis xyz="{_vec(axis)}"/>{limit}</joint>'
        )
        if rng.uniform() < 0.5:  # a massive part bolted on this link: merged into it
            extra = f"{link}_part"
            parts.append(f'<link name="{extra}">{_inertial(rng, float(rng.uniform(0.1, 3.0)))}</link>')
            parts.append(
                f'<joint name="{extra}_joint" type="fixed"><parent link="{link}"/><child link="{extra}"/>'
                f'<origin xyz="{_vec(rng.uniform(-0.3, 0.3, 3))}" rpy="{_vec(rng.uniform(-3, 3, 3))}"/></joint>'
            )
        parent = link
    parts.append(f'<link name="flange">{_inertial(rng, 0.5)}</link>')
    parts.append(
        f'<joint name="flange_joint" type="fixed"><parent link="{parent}"/><child link="flange"/>'
        f'<origin xyz="{_vec(rng.uniform(-0.2, 0.2, 3))}" rpy="{_vec(rng.uniform(-3, 3, 3))}"/></joint>'
    )
    parts.append('<link name="tool0"/>')
    parts.append(
        f'<joint name="tool_joint" type="fixed"><parent link="flange"/><child link="tool0"/>'
        f'<origin xyz="{_vec(rng.uniform(-0.2, 0.2, 3))}" rpy="{_vec(rng.uniform(-3, 3, 3))}"/></joint>'
    )
    parts.append("</robot>")
    return "\n".join(parts)


def pinocchio_from_urdf(text: str) -> pin.Model:
    """Pinocchio's own model of a URDF text, with a free-flyer root joint."""
    return pin.buildModelFromXML(text, pin.JointModelFreeFlyer())


def pinocchio_state(pm: pin.Model, model: RobotModel, state: State) -> np.ndarray:
    """Pinocchio's configuration of ``state`` (base CoM and attitude, joint positions; a
    continuous joint is ``(cos q, sin q)``): the root frame sits at the base CoM minus the CoM's
    lever in the root frame (Pinocchio's merged root inertia)."""
    A0 = state.base_attitude
    lever = pm.inertias[1].lever
    quat = pin.Quaternion(A0)
    quat.normalize()
    config = [state.base_position - A0 @ lever, quat.coeffs()]
    for j in range(model.n_joints):
        joint = pm.joints[j + 2]
        value = state.q[j]
        config.append([math.cos(value), math.sin(value)] if joint.nq == 2 else [value])
    return np.concatenate([np.asarray(c, dtype=float) for c in config])


def pinocchio_gjm_and_pose(pm: pin.Model, frame: str, config: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(J_g (6, n), ee_position, ee_attitude)`` of the frame ``frame``: ``J_m - J_b A_b^-1 A_m``
    from Pinocchio's frame Jacobian and centroidal momentum matrix."""
    data = pm.createData()
    frame_id = pm.getFrameId(frame)
    pin.forwardKinematics(pm, data, config)
    pin.updateFramePlacements(pm, data)
    J = pin.computeFrameJacobian(pm, data, config, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    Ag = pin.computeCentroidalMap(pm, data, config)
    J_g = J[:, 6:] - J[:, :6] @ np.linalg.solve(Ag[:, :6], Ag[:, 6:])
    placement = data.oMf[frame_id]
    return J_g, placement.translation.copy(), placement.rotation.copy()


def chain_urdf(joints: int, kind: str = "revolute") -> str:
    """A URDF of ``joints`` joints of ``kind`` in a chain, about 100 bytes a joint (links without
    inertia but the first; single quotes, so JSON adds nothing): the shape of a megabyte URDF
    that a careless reader walks in quadratic time."""
    inertia = "<inertia ixx='1' ixy='0' ixz='0' iyy='1' iyz='0' izz='1'/>"
    parts = [f"<robot name='big'><link name='0'><inertial><mass value='1'/>{inertia}</inertial></link>"]
    for i in range(1, joints + 1):
        parts.append(f"<link name='{i}'/><joint name='j{i}' type='{kind}'><parent link='{i - 1}'/><child link='{i}'/></joint>")
    return "".join(parts) + "</robot>"
