"""Forward kinematics of the free-floating chain (SpaceDyn recursion), batched.

Recursion (``robot-table1.md``): ``A_i = A_{i-1} Rot(s_i, q_i)``, ``p_i = r_{i-1} + A_{i-1} b_{i-1}``,
``r_i = p_i + A_i a_i``, ``p_e = r_n + A_n b_n``, ``A_e = A_n C_e``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from engine.model import RobotModel
from engine.spatial import FloatArray, is_rotation, skew


@dataclass(frozen=True)
class State:
    """Configuration of the free-floating robot.

    ``q (n,)`` joint angles in rad, ``base_position (3,)`` base CoM in world (m),
    ``base_attitude (3, 3)`` rotation base -> world. Defaults: base at the origin, identity.
    """

    q: FloatArray
    base_position: FloatArray = field(default_factory=lambda: np.zeros(3))
    base_attitude: FloatArray = field(default_factory=lambda: np.eye(3))

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=float).reshape(-1)
        pos = np.asarray(self.base_position, dtype=float)
        att = np.asarray(self.base_attitude, dtype=float)
        if not np.all(np.isfinite(q)):
            raise ValueError("q: every joint angle must be finite")
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ValueError("base_position: expected 3 finite numbers")
        if not is_rotation(att):
            raise ValueError("base_attitude: must be a rotation matrix")
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "base_position", pos)
        object.__setattr__(self, "base_attitude", att)


@dataclass(frozen=True)
class Kinematics:
    """Batched kinematic quantities; leading axis ``B`` is the batch.

    ``body_attitudes (B, n+1, 3, 3)`` and ``body_com (B, n+1, 3)`` list the base first;
    ``joint_positions (B, n, 3)``, ``joint_axes (B, n, 3)`` (world, unit), ``ee_position (B, 3)``,
    ``ee_attitude (B, 3, 3)``.
    """

    body_attitudes: FloatArray
    body_com: FloatArray
    joint_positions: FloatArray
    joint_axes: FloatArray
    ee_position: FloatArray
    ee_attitude: FloatArray

    def shifted(self, offset: FloatArray) -> Kinematics:
        """The same configuration translated by ``offset (B, 3)``."""
        return Kinematics(
            body_attitudes=self.body_attitudes,
            body_com=self.body_com + offset[:, None, :],
            joint_positions=self.joint_positions + offset[:, None, :],
            joint_axes=self.joint_axes,
            ee_position=self.ee_position + offset,
            ee_attitude=self.ee_attitude,
        )


class _ChainConstants:
    """Per-model arrays reused at every step (cached on the model instance)."""

    def __init__(self, model: RobotModel) -> None:
        self.n = model.n_joints
        self.axes = model.joint_axes
        K = skew(self.axes)
        self.K = K
        self.K2 = K @ K
        self.a = model.a_vectors
        self.b = model.b_vectors
        self.C_e = model.C_e
        self.masses = model.masses
        self.total_mass = float(self.masses.sum())
        self.inertias = model.inertias
        # Mass of links j..n for each joint j (the subtree driven by joint j).
        self.tail_mass = np.cumsum(self.masses[1:][::-1])[::-1].copy()


def chain_constants(model: RobotModel) -> _ChainConstants:
    cached = model.__dict__.get("_chain_constants")
    if cached is None:
        cached = _ChainConstants(model)
        # The model is frozen; the cache is derived data, so bypassing __setattr__ is safe.
        model.__dict__["_chain_constants"] = cached
    return cached


def kinematics_batch(model: RobotModel, q: FloatArray, base_attitude: FloatArray, base_position: FloatArray) -> Kinematics:
    """Kinematics for ``q (B, n)``, ``base_attitude (B, 3, 3)``, ``base_position (B, 3)``."""
    c = chain_constants(model)
    batch, n = q.shape
    sin = np.sin(q)[..., None, None]
    cos = np.cos(q)[..., None, None]
    local = np.eye(3) + sin * c.K + (1.0 - cos) * c.K2  # (B, n, 3, 3) Rodrigues per joint
    A = np.empty((batch, n + 1, 3, 3))
    A[:, 0] = base_attitude
    for i in range(n):
        A[:, i + 1] = A[:, i] @ local[:, i]
    joint_axes = np.einsum("bnij,nj->bni", A[:, 1:], c.axes)
    steps = np.empty((batch, 2 * n + 1, 3))
    steps[:, 0::2] = np.einsum("bnij,nj->bni", A, c.b)  # A_{i-1} b_{i-1}, i = 1..n+1
    steps[:, 1::2] = np.einsum("bnij,nj->bni", A[:, 1:], c.a)  # A_i a_i
    points = base_position[:, None, :] + np.cumsum(steps, axis=1)  # p1, r1, p2, r2, ..., r_n, p_e
    body_com = np.empty((batch, n + 1, 3))
    body_com[:, 0] = base_position
    body_com[:, 1:] = points[:, 1::2]
    return Kinematics(
        body_attitudes=A,
        body_com=body_com,
        joint_positions=points[:, 0:-1:2],
        joint_axes=joint_axes,
        ee_position=points[:, -1],
        ee_attitude=A[:, -1] @ c.C_e,
    )


def kinematics_about_com(model: RobotModel, q: FloatArray, base_attitude: FloatArray, com: FloatArray) -> Kinematics:
    """Kinematics with the base placed so that the system CoM is at ``com (B, 3)``.

    Zero linear momentum keeps the system CoM fixed, so this places the base exactly
    (no integration of the base position is needed).
    """
    c = chain_constants(model)
    kin = kinematics_batch(model, q, base_attitude, np.zeros((q.shape[0], 3)))
    com_rel = np.einsum("i,bij->bj", c.masses, kin.body_com) / c.total_mass
    return kin.shifted(com - com_rel)


def system_com(model: RobotModel, kin: Kinematics) -> FloatArray:
    """System centre of mass ``(B, 3)`` in m."""
    c = chain_constants(model)
    return np.einsum("i,bij->bj", c.masses, kin.body_com) / c.total_mass


@dataclass(frozen=True)
class ForwardKinematics:
    """Forward kinematics of one state (see :func:`forward_kinematics`)."""

    ee_position: FloatArray  # (3,) m
    ee_attitude: FloatArray  # (3, 3) end effector -> world
    link_com_positions: FloatArray  # (n, 3) m
    link_attitudes: FloatArray  # (n, 3, 3)
    joint_positions: FloatArray  # (n, 3) m
    joint_axes: FloatArray  # (n, 3) unit, world
    base_position: FloatArray  # (3,) m
    base_attitude: FloatArray  # (3, 3)
    system_com: FloatArray  # (3,) m


def _check_state(model: RobotModel, state: State) -> None:
    if state.q.shape != (model.n_joints,):
        raise ValueError(f"q: expected {model.n_joints} joint angles, got {state.q.shape[0]}")


def state_kinematics(model: RobotModel, state: State) -> Kinematics:
    """Batched kinematics (batch of one) of a :class:`State`."""
    _check_state(model, state)
    return kinematics_batch(model, state.q[None], state.base_attitude[None], state.base_position[None])


def forward_kinematics(model: RobotModel, state: State) -> ForwardKinematics:
    """End-effector pose, link CoMs, joint positions and axes of ``state`` (world frame)."""
    kin = state_kinematics(model, state)
    return ForwardKinematics(
        ee_position=kin.ee_position[0],
        ee_attitude=kin.ee_attitude[0],
        link_com_positions=kin.body_com[0, 1:],
        link_attitudes=kin.body_attitudes[0, 1:],
        joint_positions=kin.joint_positions[0],
        joint_axes=kin.joint_axes[0],
        base_position=kin.body_com[0, 0],
        base_attitude=kin.body_attitudes[0, 0],
        system_com=system_com(model, kin)[0],
    )


def as_state(model: RobotModel, q: ArrayLike) -> State:
    """A :class:`State` with the base at the origin and identity attitude."""
    state = State(np.asarray(q, dtype=float))
    _check_state(model, state)
    return state
