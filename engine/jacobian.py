"""Generalized Jacobian matrix (GJM) of a free-floating robot under zero total momentum.

Thin wrappers over the compiled kernel :func:`engine.kernels.chain.gjm`, which computes the
textbook ``J_g = J_m - J_b H_b^-1 H_bm`` (Umetani and Yoshida 1989) in its CoM-reduced form:
zero linear momentum fixes the system centre of mass, so the base rotation follows from a 3x3
angular-momentum balance (see the kernel's docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from engine.kernels import chain as chain_kernels
from engine.kernels import linalg
from engine.kernels import svd as svd_kernels
from engine.kinematics import Kinematics, State, _f64, state_kinematics
from engine.model import RobotModel
from engine.spatial import FloatArray, cross


def gjm_batch(
    model: RobotModel, q: ArrayLike, base_attitude: ArrayLike, base_position: ArrayLike, about_com: bool = False
) -> tuple[FloatArray, FloatArray]:
    """``(J_g (B, 6, n), base_map (B, 6, n))`` of configurations ``q (B, n)`` rad with base
    attitudes ``(B, 3, 3)`` and base positions ``(B, 3)`` m (or system CoMs, ``about_com``).

    ``J_g`` maps joint rates (rad/s) to the end-effector twist ``[v_e; w_e]`` (m/s, rad/s,
    world axes); ``base_map`` maps them to the base twist ``[v_0; w_0]`` (base CoM velocity,
    base angular velocity, world axes).
    """
    q = np.asarray(q, dtype=float)
    batch, n = q.shape
    J = np.empty((batch, 6, n))
    base_map = np.empty((batch, 6, n))
    A0 = _f64(base_attitude, (batch, 3, 3))
    chain_kernels.gjm_many(model.chain, _f64(q, (batch, n)), A0, _f64(base_position, (batch, 3)), about_com, J, base_map)
    return J, base_map


def fixed_base_jacobian_batch(kin: Kinematics, prismatic: ArrayLike | None = None) -> FloatArray:
    """Geometric Jacobian ``(B, 6, n)`` of the same chain with the base held fixed (``prismatic
    (n,)`` flags the sliding joints: their columns are ``[k; 0]``)."""
    k = kin.joint_axes
    J = np.empty((k.shape[0], 6, k.shape[1]))
    J[:, :3] = np.swapaxes(cross(k, kin.ee_position[:, None, :] - kin.joint_positions), 1, 2)
    J[:, 3:] = np.swapaxes(k, 1, 2)
    if prismatic is not None:
        slides = np.asarray(prismatic, dtype=bool)
        J[:, :3, slides] = J[:, 3:, slides]
        J[:, 3:, slides] = 0.0
    return J


@dataclass(frozen=True)
class GJMResult:
    """The GJM at one state and the quantities derived from it."""

    J_g: FloatArray  # (6, n): qd (rad/s) -> [v_e (m/s); w_e (rad/s)], world axes
    base_velocity_map: FloatArray  # (6, n): qd -> [v_0; w_0] of the base, world axes
    singular_values: FloatArray  # (min(6, n),) descending
    determinant: float | None  # det J_g when n == 6, else None
    manipulability: float  # product of singular values (= sqrt(det(J_g J_g^T)) for n >= 6)
    condition_number: float  # sigma_max / sigma_min (inf where sigma_min <= max(6, n) eps sigma_max)
    ee_position: FloatArray  # (3,) m, the end-effector pose at the same state
    ee_attitude: FloatArray  # (3, 3)
    success: bool = True
    message: str = "ok"


NOT_FINITE = (
    "the GJM at this state is not finite (NaN or infinite entries): the robot's masses or inertias are too small, "
    "or too far apart in scale, for double precision"
)


def generalized_jacobian(model: RobotModel, state: State) -> GJMResult:
    """GJM of ``model`` at ``state`` with zero total momentum (free floating); ``success`` is
    false (and ``message`` says why) when it is not finite."""
    kin = state_kinematics(model, state)
    J_all, base_map = gjm_batch(model, state.q[None], state.base_attitude[None], state.base_position[None])
    J = J_all[0]
    n = model.n_joints
    m = min(6, n)
    U, sv, V = np.empty((1, 6, m)), np.empty((1, m)), np.empty((1, n, m))
    svd_kernels.svd_many(J_all, U, sv, V)
    s = sv[0]
    determinant = float(linalg.det6(J, np.empty((6, 6)))) if n == 6 else None
    # singular to working precision (numpy's matrix_rank tolerance): the ratio of a rounding residue
    # to sigma_max (6.5e15 for arm7 stretched out) would read as a condition number
    singular = not s[-1] > s[0] * max(6, n) * np.finfo(float).eps
    cond = float("inf") if singular else float(s[0] / s[-1])
    finite = bool(np.all(np.isfinite(J)) and np.all(np.isfinite(s)) and np.isfinite(np.prod(s)))
    return GJMResult(
        J_g=J,
        base_velocity_map=base_map[0],
        singular_values=s,
        determinant=determinant,
        manipulability=float(np.prod(s)),
        condition_number=cond,
        ee_position=kin.ee_position[0],
        ee_attitude=kin.ee_attitude[0],
        success=finite,
        message="ok" if finite else NOT_FINITE,
    )
