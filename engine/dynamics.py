"""Joint torques of a free-floating robot: thin wrappers over the compiled floating-base
recursive Newton-Euler of :mod:`engine.kernels.dynamics`.

No gravity and no external wrench: the base twist follows from zero momentum (what the GJM's
base map gives, found in the recursion), its acceleration from zero rate of change of momentum.
Along a plan the joint motion is the executed trajectory of :mod:`engine.executed` (the plan's
own accelerations are impulses).
The torques and the mount wrench do not depend on where the system is or how it is turned (no
gravity), only on ``q``, ``qd`` and ``qdd``; the base attitude only sets the axes of the base
twist and acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.executed import ExecutedTrajectory, from_plan
from engine.kernels import dynamics as dynamics_kernels
from engine.kinematics import _f64
from engine.model import RobotModel
from engine.planner import PlanResult
from engine.spatial import FloatArray


@dataclass(frozen=True)
class InverseDynamics:
    """Free-floating inverse dynamics at ``M`` samples (time-major, SI units).

    Joint quantities are rad, rad/s, rad/s^2 and N m for revolute joints, m, m/s, m/s^2 and N
    for prismatic ones. The mount wrench is what the arm exerts on the carrier at joint 1: force
    (N) and torque about joint 1's origin (N m), in the carrier frame. The base twist ``[v_0;
    w_0]`` and acceleration ``[dv_0/dt; dw_0/dt]`` are those of the base CoM, in world axes (the
    axes of the given base attitudes)."""

    t: FloatArray | None  # (M,) s, when known
    joint_positions: FloatArray  # (M, n)
    joint_velocities: FloatArray  # (M, n)
    joint_accelerations: FloatArray  # (M, n)
    joint_torques: FloatArray  # (M, n)
    mount_force: FloatArray  # (M, 3) N
    mount_torque: FloatArray  # (M, 3) N m
    base_twist: FloatArray  # (M, 6) m/s, rad/s
    base_acceleration: FloatArray  # (M, 6) m/s^2, rad/s^2
    success: bool  # false if a sample was not finite (its rows are NaN)

    @property
    def peak_torques(self) -> FloatArray:
        """``(n,)`` the largest ``|torque|`` of each joint over the samples."""
        peaks: FloatArray = np.abs(self.joint_torques).max(axis=0)
        return peaks


def inverse_dynamics(
    model: RobotModel,
    q: ArrayLike,
    qd: ArrayLike,
    qdd: ArrayLike,
    base_attitude: ArrayLike | None = None,
    base_position: ArrayLike | None = None,
    t: ArrayLike | None = None,
) -> InverseDynamics:
    """Joint torques, mount wrench and base acceleration of the free-floating ``model`` at joint
    positions, rates and accelerations ``q``, ``qd``, ``qdd (M, n)``, with the base twist that
    zero momentum gives. ``base_attitude ((M,) 3, 3)`` (default identity) and ``base_position
    ((M,) 3)`` m (default the origin) only place the system; ``t (M,)`` s is carried along."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ParameterError("q", f"expected (M, {model.n_joints}) joint positions, got {q.shape}")
    M, n = q.shape
    A0 = _f64(np.eye(3) if base_attitude is None else base_attitude, (M, 3, 3))
    origin = _f64(np.zeros(3) if base_position is None else base_position, (M, 3))
    q, qd, qdd = _f64(q, (M, n)), _f64(qd, (M, n)), _f64(qdd, (M, n))
    tau = np.empty((M, n))
    force = np.empty((M, 3))
    torque = np.empty((M, 3))
    twist = np.empty((M, 6))
    acc = np.empty((M, 6))
    bad = dynamics_kernels.inverse_dynamics_many(model.chain, q, qd, qdd, A0, origin, tau, force, torque, twist, acc)
    return InverseDynamics(
        t=None if t is None else np.asarray(t, dtype=float),
        joint_positions=q,
        joint_velocities=qd,
        joint_accelerations=qdd,
        joint_torques=tau,
        mount_force=force,
        mount_torque=torque,
        base_twist=twist,
        base_acceleration=acc,
        success=bad == 0 and bool(np.all(np.isfinite(tau))),
    )


def plan_dynamics(model: RobotModel, plan_result: PlanResult, trajectory: ExecutedTrajectory | None = None) -> InverseDynamics:
    """Inverse dynamics at the plan's samples along its executed trajectory (by default
    :func:`engine.executed.from_plan`), with the plan's base poses (they set only the axes of
    the base twist and acceleration). The executed accelerations are linear between the
    samples, so for slow motion the torque peaks are at the samples."""
    trajectory = trajectory or from_plan(plan_result)
    return inverse_dynamics(
        model,
        trajectory.q,
        trajectory.qd,
        trajectory.qdd,
        plan_result.base_attitude,
        plan_result.base_position,
        t=trajectory.t,
    )
