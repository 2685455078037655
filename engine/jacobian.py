"""Generalized Jacobian matrix (GJM) of a free-floating robot under zero total momentum.

The textbook form (Umetani and Yoshida 1989) is ``J_g = J_m - J_b H_b^-1 H_bm`` with the
6x6 base inertia ``H_b``. Zero linear momentum fixes the system centre of mass, so the base
rotation follows from the 3x3 angular-momentum balance about the system CoM,
``H_s w_0 + H_sq qd = 0``; this is algebraically identical and only needs a 3x3 solve:

- ``w_0 = -H_s^-1 H_sq qd``
- ``v_0 = [r_g - r_0]x w_0 - J_Tw qd / M``
- ``v_e = (J_mv - J_Tw / M - [p_e - r_g]x H_s^-1 H_sq) qd``, ``w_e = (J_mw - H_s^-1 H_sq) qd``

where ``H_s = sum_i I_i + m_i [rho_i]x^T [rho_i]x`` (``rho_i = r_i - r_g``),
``H_sq`` column j ``= sum_{i>=j} I_i k_j + m_i rho_i x (k_j x (r_i - p_j))`` and
``J_Tw`` column j ``= sum_{i>=j} m_i k_j x (r_i - p_j)``. The sums over the subtree of joint j
are reverse cumulative sums, so the whole GJM is O(n) per configuration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.kinematics import Kinematics, State, chain_constants, state_kinematics
from engine.model import RobotModel
from engine.spatial import FloatArray, cross, skew


def _tail_sum(x: FloatArray) -> FloatArray:
    """Reverse cumulative sum over axis 1: ``out[:, j] = sum_{i >= j} x[:, i]``."""
    return np.flip(np.cumsum(np.flip(x, axis=1), axis=1), axis=1)


def gjm_batch(model: RobotModel, kin: Kinematics) -> tuple[FloatArray, FloatArray]:
    """``(J_g (B, 6, n), base_map (B, 6, n))``.

    ``J_g`` maps joint rates (rad/s) to the end-effector twist ``[v_e; w_e]`` (m/s, rad/s,
    world axes). ``base_map`` maps them to the base twist ``[v_0; w_0]`` (base CoM velocity,
    base angular velocity, world axes).
    """
    c = chain_constants(model)
    m = c.masses
    A = kin.body_attitudes
    r = kin.body_com
    k = kin.joint_axes
    p = kin.joint_positions
    r_g = np.einsum("i,bij->bj", m, r) / c.total_mass
    rho = r - r_g[:, None, :]
    inertia_world = A @ c.inertias @ np.swapaxes(A, -1, -2)
    rho_sq = np.einsum("bij,bij->bi", rho, rho)
    # Body inertia about the system CoM (parallel-axis theorem), (B, n+1, 3, 3).
    T = inertia_world - m[:, None, None] * (rho[..., :, None] * rho[..., None, :])
    T[..., 0, 0] += m * rho_sq
    T[..., 1, 1] += m * rho_sq
    T[..., 2, 2] += m * rho_sq
    H_s = T.sum(axis=1)
    tail_T = _tail_sum(T[:, 1:])
    tail_W = _tail_sum(m[None, 1:, None] * rho[:, 1:])
    c_j = p - r_g[:, None, :]
    H_sq = np.einsum("bnij,bnj->bin", tail_T, k) - np.swapaxes(cross(tail_W, cross(k, c_j)), 1, 2)
    J_Tw = np.swapaxes(cross(k, tail_W - c.tail_mass[None, :, None] * c_j), 1, 2)  # (B, 3, n)
    Omega = -np.linalg.solve(H_s, H_sq)  # (B, 3, n): w_0 = Omega qd
    J_mv = np.swapaxes(cross(k, kin.ee_position[:, None, :] - p), 1, 2)
    J_g = np.empty((r.shape[0], 6, c.n))
    J_g[:, :3] = J_mv - J_Tw / c.total_mass - skew(kin.ee_position - r_g) @ Omega
    J_g[:, 3:] = np.swapaxes(k, 1, 2) + Omega
    base_map = np.empty_like(J_g)
    base_map[:, :3] = skew(r_g - kin.body_com[:, 0]) @ Omega - J_Tw / c.total_mass
    base_map[:, 3:] = Omega
    return J_g, base_map


def fixed_base_jacobian_batch(kin: Kinematics) -> FloatArray:
    """Geometric Jacobian ``(B, 6, n)`` of the same chain with the base held fixed."""
    k = kin.joint_axes
    J = np.empty((k.shape[0], 6, k.shape[1]))
    J[:, :3] = np.swapaxes(cross(k, kin.ee_position[:, None, :] - kin.joint_positions), 1, 2)
    J[:, 3:] = np.swapaxes(k, 1, 2)
    return J


@dataclass(frozen=True)
class GJMResult:
    """The GJM at one state and the quantities derived from it."""

    J_g: FloatArray  # (6, n): qd (rad/s) -> [v_e (m/s); w_e (rad/s)], world axes
    base_velocity_map: FloatArray  # (6, n): qd -> [v_0; w_0] of the base, world axes
    singular_values: FloatArray  # (min(6, n),) descending
    determinant: float | None  # det J_g when n == 6, else None
    manipulability: float  # product of singular values (= sqrt(det(J_g J_g^T)) for n >= 6)
    condition_number: float  # sigma_max / sigma_min (inf at a singularity)
    success: bool = True
    message: str = "ok"


def generalized_jacobian(model: RobotModel, state: State) -> GJMResult:
    """GJM of ``model`` at ``state`` with zero total momentum (free floating)."""
    kin = state_kinematics(model, state)
    J_g, base_map = gjm_batch(model, kin)
    J = J_g[0]
    sv = np.linalg.svd(J, compute_uv=False)
    determinant = float(np.linalg.det(J)) if J.shape[0] == J.shape[1] else None
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")
    return GJMResult(
        J_g=J,
        base_velocity_map=base_map[0],
        singular_values=sv,
        determinant=determinant,
        manipulability=float(np.prod(sv)),
        condition_number=cond,
    )
