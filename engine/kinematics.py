"""Forward kinematics of the free-floating chain: thin wrappers over the compiled kernel
:func:`engine.kernels.chain.kinematics` (the SpaceDyn recursion, docs/engine.md):
``A_i = A_{i-1} Rot(s_i, q_i)``, ``p_i = r_{i-1} + A_{i-1} b_{i-1}``, ``r_i = p_i + A_i a_i``,
``p_e = r_n + A_n b_n``, ``A_e = A_n C_e``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.kernels import chain as chain_kernels
from engine.model import RobotModel
from engine.spatial import FloatArray, is_rotation


@dataclass(frozen=True)
class State:
    """Configuration of the free-floating robot.

    ``q (n,)`` joint positions (rad for revolute joints, m for prismatic ones),
    ``base_position (3,)`` base CoM in world (m),
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
            raise ParameterError("q", "every joint position must be finite")
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise ParameterError("base_position", "expected 3 finite numbers")
        if not is_rotation(att):
            raise ParameterError("base_attitude", "must be a rotation matrix")
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


def _f64(x: ArrayLike, shape: tuple[int, ...]) -> FloatArray:
    arr: FloatArray = np.require(np.broadcast_to(np.asarray(x, dtype=float), shape), np.float64, ["C", "W"])
    return arr


def _chain(model: RobotModel, q: ArrayLike, base_attitude: ArrayLike, origin: ArrayLike, about_com: bool) -> Kinematics:
    q = np.asarray(q, dtype=float)
    batch, n = q.shape
    out = Kinematics(
        body_attitudes=np.empty((batch, n + 1, 3, 3)),
        body_com=np.empty((batch, n + 1, 3)),
        joint_positions=np.empty((batch, n, 3)),
        joint_axes=np.empty((batch, n, 3)),
        ee_position=np.empty((batch, 3)),
        ee_attitude=np.empty((batch, 3, 3)),
    )
    chain_kernels.kinematics_many(
        model.chain,
        _f64(q, (batch, n)),
        _f64(base_attitude, (batch, 3, 3)),
        _f64(origin, (batch, 3)),
        about_com,
        out.body_attitudes,
        out.body_com,
        out.joint_positions,
        out.joint_axes,
        out.ee_position,
        out.ee_attitude,
    )
    return out


def kinematics_batch(model: RobotModel, q: ArrayLike, base_attitude: ArrayLike, base_position: ArrayLike) -> Kinematics:
    """Kinematics for ``q (B, n)`` rad, ``base_attitude (B, 3, 3)``, ``base_position (B, 3)`` m."""
    return _chain(model, q, base_attitude, base_position, about_com=False)


def kinematics_about_com(model: RobotModel, q: ArrayLike, base_attitude: ArrayLike, com: ArrayLike) -> Kinematics:
    """Kinematics with the base placed so that the system CoM is at ``com (B, 3)``.

    Zero linear momentum keeps the system CoM fixed, so this places the base exactly
    (no integration of the base position is needed).
    """
    return _chain(model, q, base_attitude, com, about_com=True)


def system_com(model: RobotModel, kin: Kinematics) -> FloatArray:
    """System centre of mass ``(B, 3)`` in m."""
    com: FloatArray = np.einsum("i,bik->bk", model.masses, kin.body_com) / model.total_mass
    return com


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
        raise ParameterError("q", f"expected {model.n_joints} joint angles, got {state.q.shape[0]}")


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
