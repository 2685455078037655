"""Test oracle: the former replay of the engine (``solve_ivp`` with a numpy right-hand side).

The planned joint motion (``q_k`` with constant ``qd_k`` over each step) is replayed and the
base motion integrated with ``scipy.integrate.solve_ivp`` (DOP853, tight tolerances), step by
step. The base velocity comes from the textbook 6x6 momentum equations
``H_b [v_0; w_0] + H_bm qd = 0`` (Umetani and Yoshida 1989) built body by body, a different
formulation from the planner's reduced 3x3 one; the base attitude is integrated as a unit
quaternion, the base position as a state (not from the fixed CoM, so CoM drift is a check).
"""

from __future__ import annotations

import numpy as np
from oracle.kinematics import Kinematics, chain_constants, kinematics_batch
from oracle.spatial import FloatArray, matrix_to_quaternion, quaternion_to_matrix, skew
from scipy.integrate import solve_ivp

from engine.model import RobotModel
from engine.planner import PlanResult
from engine.replay import ReplayResult, summarise

RTOL = 1e-11
ATOL = 1e-13


def _body_jacobians(kin: Kinematics) -> FloatArray:
    """Per-body Jacobians ``(n+1, 6, n)`` of CoM velocity and angular velocity w.r.t. the
    joint rates (base fixed), for a batch-of-one ``kin``; body 0 (the base) has zeros.
    Column j of body i is ``[k_j x (r_i - p_j); k_j]`` for ``j < i`` (joint j+1 moves body i)."""
    r = kin.body_com[0]
    p = kin.joint_positions[0]
    k = kin.joint_axes[0]
    n = p.shape[0]
    moves = np.arange(n)[None, :] < np.arange(n + 1)[:, None]  # (n+1, n): joint j moves body i
    lever = r[:, None, :] - p[None, :, :]  # (n+1, n, 3)
    J = np.zeros((n + 1, 6, n))
    J[:, :3, :] = np.swapaxes(np.cross(np.broadcast_to(k, lever.shape), lever) * moves[..., None], 1, 2)
    J[:, 3:, :] = np.swapaxes(np.broadcast_to(k, lever.shape) * moves[..., None], 1, 2)
    return J


def _world_inertias(model: RobotModel, kin: Kinematics) -> FloatArray:
    A = kin.body_attitudes[0]
    inertias: FloatArray = np.einsum("bij,bjk,blk->bil", A, chain_constants(model).inertias, A)
    return inertias


def _momentum_matrices(model: RobotModel, kin: Kinematics) -> tuple[FloatArray, FloatArray]:
    """``(H_b (6, 6), H_bm (6, n))`` with momenta ``[P; L_0] = H_b [v_0; w_0] + H_bm qd``
    (``L_0`` about the base CoM), summed body by body."""
    m = chain_constants(model).masses
    rel = kin.body_com[0] - kin.body_com[0, 0]  # (n+1, 3) r_i - r_0
    S = skew(rel)
    I_w = _world_inertias(model, kin)
    Jb = _body_jacobians(kin)
    H_b = np.zeros((6, 6))
    H_b[:3, :3] = m.sum() * np.eye(3)
    H_b[:3, 3:] = -np.einsum("i,ijk->jk", m, S)
    H_b[3:, :3] = -H_b[:3, 3:]
    H_b[3:, 3:] = (I_w - m[:, None, None] * (S @ S)).sum(axis=0)
    H_bm = np.empty((6, Jb.shape[2]))
    H_bm[:3] = np.einsum("i,ijk->jk", m, Jb[:, :3])
    H_bm[3:] = (I_w @ Jb[:, 3:] + m[:, None, None] * (S @ Jb[:, :3])).sum(axis=0)
    return H_b, H_bm


def base_twist_from_momentum(model: RobotModel, kin: Kinematics, qd: FloatArray) -> FloatArray:
    """Base twist ``[v_0; w_0] (6,)`` giving zero total momentum: ``H_b x_b = -H_bm qd``."""
    H_b, H_bm = _momentum_matrices(model, kin)
    return -np.linalg.solve(H_b, H_bm @ qd)


def momentum(model: RobotModel, kin: Kinematics, qd: FloatArray, base_twist: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Total linear momentum (N s) and angular momentum about the world origin (N m s),
    summed body by body from each body's own velocity, for a batch-of-one ``kin``."""
    m = chain_constants(model).masses
    r = kin.body_com[0]
    I_w = _world_inertias(model, kin)
    Jb = _body_jacobians(kin)
    v0, w0 = base_twist[:3], base_twist[3:]
    v = v0 + np.cross(w0, r - r[0]) + Jb[:, :3] @ qd  # (n+1, 3)
    w = w0 + Jb[:, 3:] @ qd
    P = m @ v
    L = (I_w @ w[:, :, None])[:, :, 0].sum(axis=0) + (m[:, None] * np.cross(r, v)).sum(axis=0)
    return P, L


def replay(model: RobotModel, plan_result: PlanResult, *, rtol: float = RTOL, atol: float = ATOL) -> ReplayResult:
    """Replay ``plan_result``'s joint motion and integrate the base with ``solve_ivp``."""
    t = plan_result.t
    q_plan = plan_result.q
    qd_plan = plan_result.qd
    if not (np.all(np.isfinite(q_plan)) and np.all(np.isfinite(qd_plan))):
        nan = float("nan")
        empty = np.full((t.shape[0], 3), nan)
        return ReplayResult(
            t,
            empty,
            np.full((t.shape[0], 3, 3), nan),
            empty,
            np.full((t.shape[0], 3, 3), nan),
            nan,
            nan,
            nan,
            nan,
            nan,
            nan,
            nan,
            nan,
            nan,
            nan,
            0,
            False,
            "the plan is not finite, nothing to replay",
        )

    def kin_at(q: FloatArray, y: FloatArray) -> Kinematics:
        A0 = quaternion_to_matrix(y[3:])
        return kinematics_batch(model, q[None], A0[None], y[None, :3])

    n_samples = t.shape[0]
    ys = np.empty((n_samples, 7))
    ys[0, :3] = plan_result.base_position[0]
    ys[0, 3:] = matrix_to_quaternion(plan_result.base_attitude[0])
    nfev = 0
    for k in range(n_samples - 1):
        q_k, qd_k, t_k = q_plan[k], qd_plan[k], t[k]

        def rhs(time: float, y: FloatArray, q_k: FloatArray = q_k, qd_k: FloatArray = qd_k, t_k: float = t_k) -> FloatArray:
            kin = kin_at(q_k + qd_k * (time - t_k), y)
            twist = base_twist_from_momentum(model, kin, qd_k)
            w = twist[3:]
            quat = y[3:]
            # World-frame angular velocity: quat_dot = 0.5 [0, w] (x) quat.
            dq = 0.5 * np.array(
                [
                    -w @ quat[1:],
                    quat[0] * w[0] + w[1] * quat[3] - w[2] * quat[2],
                    quat[0] * w[1] + w[2] * quat[1] - w[0] * quat[3],
                    quat[0] * w[2] + w[0] * quat[2] - w[1] * quat[1],
                ]
            )
            return np.concatenate([twist[:3], dq])

        sol = solve_ivp(rhs, (t_k, t[k + 1]), ys[k], method="DOP853", rtol=rtol, atol=atol)
        nfev += int(sol.nfev)
        if not sol.success:
            raise RuntimeError(f"replay integration failed at t = {t_k:g} s: {sol.message}")
        ys[k + 1] = sol.y[:, -1]
        ys[k + 1, 3:] /= np.linalg.norm(ys[k + 1, 3:])

    c = chain_constants(model)
    ee_p = np.empty((n_samples, 3))
    ee_A = np.empty((n_samples, 3, 3))
    base_A = np.empty((n_samples, 3, 3))
    lin_res = np.empty(n_samples)
    ang_res = np.empty(n_samples)
    com = np.empty((n_samples, 3))
    for k in range(n_samples):
        kin = kin_at(q_plan[k], ys[k])
        ee_p[k] = kin.ee_position[0]
        ee_A[k] = kin.ee_attitude[0]
        base_A[k] = kin.body_attitudes[0, 0]
        twist = base_twist_from_momentum(model, kin, qd_plan[k])
        P, L = momentum(model, kin, qd_plan[k], twist)
        lin_res[k] = np.linalg.norm(P)
        ang_res[k] = np.linalg.norm(L)
        com[k] = c.masses @ kin.body_com[0] / c.total_mass

    return summarise(plan_result, ys[:, :3].copy(), ee_p, ee_A, base_A, lin_res, ang_res, com, nfev)
