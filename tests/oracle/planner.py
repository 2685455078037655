"""Test oracle: the former numpy planner of the engine (the paper's Figure 2), batched over
parameter sets, with the base attitude step of the compiled planner written in numpy.

At each sample ``t_k`` (k = 0..N): kinematics and GJM at the current state, commanded twist
(the path's mean twist over the step, plus ``feedback_gain * pose_error`` if asked), robust
inverse of the tracked rows (all six for a pose task, the linear three for a position task) ->
joint rates ``qd_k``, plus a secondary objective's null-space motion written with numpy's
matrices; then ``q_{k+1} = q_k + qd_k dt``, the base attitude ``A_0 <- exp([w_0 dt]x) A_0`` with
``w_0`` from angular-momentum conservation, and the base position from the fixed system centre
of mass (linear momentum stays exactly zero). Revolute joints only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from oracle.inverses import SVD, thin_svd
from oracle.jacobian import gjm_batch
from oracle.kinematics import kinematics_about_com, kinematics_batch, system_com
from oracle.metrics import Objective, compute_metrics
from oracle.spatial import FloatArray, exp_so3, log_so3

from engine.errors import ParameterError
from engine.inverses import make_inverse
from engine.kernels.redundancy import NULL_SPACE_DAMPING
from engine.metrics import Column, Metrics
from engine.model import RobotModel
from engine.planner import ATTITUDE_TOLERANCE_RAD, POSITION_TOLERANCE_M, PlanOptions, PlanResult, _verdict
from engine.redundancy import joint_centres
from engine.trajectory import TRACKS, CartesianTask

SUBSTEP_ANGLE = 0.25
MAX_SUBSTEPS = 64

#: Parameter sets of one method: ``{name: (B,) values}`` or a list of ``{name: value}``.
ParamSets = Mapping[str, Sequence[float] | FloatArray] | Sequence[Mapping[str, float]]


@dataclass(frozen=True)
class _Trace:
    """Raw arrays of a batched simulation, time-major after the batch axis."""

    t: FloatArray
    q: FloatArray  # (B, N+1, n)
    qd: FloatArray  # (B, N+1, n)
    base_position: FloatArray  # (B, N+1, 3)
    base_attitude: FloatArray  # (B, N+1, 3, 3)
    ee_position: FloatArray  # (B, N+1, 3)
    ee_attitude: FloatArray  # (B, N+1, 3, 3)
    singular_values: FloatArray  # (B, N+1, m)
    det_J_g: FloatArray  # (B, N+1)
    damping: FloatArray  # (B, N+1, m)
    p_des: FloatArray  # (N+1, 3) desired end-effector positions
    A_des: FloatArray  # (N+1, 3, 3) desired end-effector attitudes


def _simulate(
    model: RobotModel,
    task: CartesianTask,
    inverse: Any,
    batch: int,
    feedback_gain: float,
    integrator: str = "magnus",
    substep_angle: float = SUBSTEP_ANGLE,
    secondary: Any = None,
) -> _Trace:
    n = model.n_joints
    rows = TRACKS[task.tracks]
    centre = joint_centres(model, task.q0)
    if task.q0.shape != (n,):
        raise ParameterError("q0", f"task has {task.q0.shape[0]} joint angles, robot has {n} joints")
    if not math.isfinite(feedback_gain) or feedback_gain < 0.0:
        raise ParameterError("feedback_gain", "must be finite and >= 0")
    N = task.n_steps
    m = min(rows, n)
    dt = task.dt
    t = task.times()
    twists = task.step_twists()
    p_des, A_des = task.desired_pose(t)

    q = np.tile(task.q0, (batch, 1))
    A0 = np.tile(np.eye(3), (batch, 1, 1))
    kin = kinematics_batch(model, q, A0, np.zeros((batch, 3)))
    com = system_com(model, kin)

    out_q = np.empty((batch, N + 1, n))
    out_qd = np.empty((batch, N + 1, n))
    out_base_p = np.empty((batch, N + 1, 3))
    out_base_A = np.empty((batch, N + 1, 3, 3))
    out_p = np.empty((batch, N + 1, 3))
    out_A = np.empty((batch, N + 1, 3, 3))
    out_s = np.empty((batch, N + 1, m))
    out_det = np.full((batch, N + 1), np.nan)
    out_damp = np.empty((batch, N + 1, m))
    square = n == rows
    with np.errstate(all="ignore"):  # a diverging plan yields inf/nan, reported by the metrics
        for k in range(N + 1):
            if k > 0:
                kin = kinematics_about_com(model, q, A0, com)
            J_g, base_map = gjm_batch(model, kin)
            J_g = np.ascontiguousarray(J_g[:, :rows])
            svd = thin_svd(J_g) if np.all(np.isfinite(J_g)) else _nan_svd(J_g)
            xdot = np.broadcast_to(twists[k], (batch, 6))
            if feedback_gain > 0.0:
                error = np.empty((batch, 6))
                error[:, :3] = p_des[k] - kin.ee_position
                error[:, 3:] = log_so3(A_des[k] @ np.swapaxes(kin.ee_attitude, -1, -2))
                xdot = xdot + feedback_gain * error
            step = inverse.solve(J_g, xdot[:, :rows], svd)
            if secondary is not None and n > rows:
                for b in range(batch):
                    step.qd[b] = _null_space(secondary, svd.Vt[b].T, base_map[b, 3:], q[b], centre, step.qd[b])
            out_q[:, k] = q
            out_qd[:, k] = step.qd
            out_base_p[:, k] = kin.body_com[:, 0]
            out_base_A[:, k] = A0
            out_p[:, k] = kin.ee_position
            out_A[:, k] = kin.ee_attitude
            out_s[:, k] = svd.s
            out_damp[:, k] = step.damping
            if square:
                out_det[:, k] = np.linalg.det(J_g) if np.all(np.isfinite(J_g)) else np.nan
            if k < N:
                w0 = np.einsum("bij,bj->bi", base_map[:, 3:], step.qd)
                if integrator == "euler":
                    A0 = exp_so3(w0 * dt) @ A0
                else:
                    A0 = _magnus_step(model, q, step.qd, A0, w0, com, dt, substep_angle)
                q = q + step.qd * dt
    return _Trace(t, out_q, out_qd, out_base_p, out_base_A, out_p, out_A, out_s, out_det, out_damp, p_des, A_des)


def _null_space(
    secondary: Any, V: FloatArray, Omega: FloatArray, q: FloatArray, centre: FloatArray, qd: FloatArray
) -> FloatArray:
    """The secondary objective (:mod:`engine.redundancy`) with numpy's matrices: the projector
    ``N = I - V V^T`` and, for ``min_base_rotation``, the damped least-squares choice of the
    null-space motion that cancels the carrier's angular velocity ``Omega qd``."""
    N = np.eye(qd.shape[0]) - V @ V.T
    if secondary.name == "joint_centering":
        return qd + N @ (-secondary.gain * (q - centre))
    P = Omega @ N
    y = np.linalg.solve(P @ P.T + NULL_SPACE_DAMPING**2 * np.eye(3), Omega @ qd)
    return qd - secondary.gain * P.T @ y


def _body_rate(model: RobotModel, q: FloatArray, qd: FloatArray, com: FloatArray) -> FloatArray:
    """Base angular velocity in the base frame ``(B, 3)`` at ``q`` for joint rates ``qd``
    (independent of the base attitude: computed with the identity)."""
    eye = np.tile(np.eye(3), (q.shape[0], 1, 1))
    _, bm = gjm_batch(model, kinematics_about_com(model, q, eye, com))
    return np.einsum("bij,bj->bi", bm[:, 3:], qd)


def _magnus_step(model, q, qd, A0, w0_world, com, dt, substep_angle):
    """Fourth-order Magnus (Simpson) update of the base attitude over one step of linear joint
    motion, split into sub-steps of at most ``substep_angle`` of joint travel."""
    travel = float(np.max(np.abs(qd))) * dt if np.all(np.isfinite(qd)) else 0.0
    S = int(min(MAX_SUBSTEPS, max(1, math.ceil(travel / substep_angle)))) if substep_angle > 0 else 1
    h = dt / S
    wa = np.einsum("bji,bj->bi", A0, w0_world)  # body frame
    for j in range(S):
        ta = j * h
        wm = _body_rate(model, q + qd * (ta + 0.5 * h), qd, com)
        wb = _body_rate(model, q + qd * dt if j == S - 1 else q + qd * (ta + h), qd, com)
        omega = (h / 6.0) * (wa + 4.0 * wm + wb) + (h * h / 12.0) * np.cross(wa, wb)
        A0 = A0 @ exp_so3(omega)
        wa = wb
    return A0


def _nan_svd(J: FloatArray) -> SVD:
    """SVD of a batch where some members diverged: NaN for those, the real SVD for the rest."""
    ok = np.all(np.isfinite(J), axis=(-2, -1))
    batch, rows, cols = J.shape
    m = min(rows, cols)
    U = np.full((batch, rows, m), np.nan)
    s = np.full((batch, m), np.nan)
    Vt = np.full((batch, m, cols), np.nan)
    if np.any(ok):
        good = thin_svd(J[ok])
        U[ok], s[ok], Vt[ok] = good.U, good.s, good.Vt
    return SVD(U, s, Vt)


@dataclass(frozen=True)
class _Errors:
    position: FloatArray  # (B, N+1) m
    attitude: FloatArray  # (B, N+1) rad, rotation angle
    coupled: FloatArray  # (B, N+1) m rad, eq. 18 as printed
    p_des: FloatArray  # (N+1, 3)
    A_des: FloatArray  # (N+1, 3, 3)


def _errors(trace: _Trace) -> _Errors:
    p_des, A_des = trace.p_des, trace.A_des
    dp = trace.ee_position - p_des
    finite = np.all(np.isfinite(trace.ee_attitude), axis=(-2, -1))
    safe = np.where(finite[..., None, None], trace.ee_attitude, np.eye(3))
    dphi = log_so3(safe @ np.swapaxes(A_des, -1, -2))  # world-axes rotation vector of the error
    dphi = np.where(finite[..., None], dphi, np.nan)
    return _Errors(
        position=np.linalg.norm(dp, axis=-1),
        attitude=np.linalg.norm(dphi, axis=-1),
        coupled=np.linalg.norm(dp * dphi, axis=-1),
        p_des=p_des,
        A_des=A_des,
    )


def _batch_metrics(task: CartesianTask, trace: _Trace, errors: _Errors, objective: Objective) -> Metrics[Column]:
    peak = np.max(np.abs(trace.qd), axis=1)
    return compute_metrics(
        trace.t,
        errors.position,
        errors.attitude,
        errors.coupled,
        peak,
        trace.singular_values[..., -1],
        np.abs(trace.det_J_g),
        task.joint_speed_limit,
        objective,
    )


def plan(
    model: RobotModel,
    task: CartesianTask,
    inverse: Any,
    *,
    feedback_gain: float = 0.0,
    weights: tuple[float, float] = (0.5, 0.5),
    aggregation: str = "max",
    attitude_term: str = "angle",
    position_tolerance: float = POSITION_TOLERANCE_M,
    attitude_tolerance: float = ATTITUDE_TOLERANCE_RAD,
    integrator: str = "magnus",
    substep_angle: float = SUBSTEP_ANGLE,
    secondary: Any = None,
) -> PlanResult:
    """Plan ``task`` with ``inverse``. ``success`` is false (with a message) if the plan
    diverged, misses the target pose by more than the tolerances, or breaks the joint
    speed limit; the arrays and metrics are returned in every case."""
    objective = Objective(weights, aggregation, attitude_term)
    trace = _simulate(model, task, inverse, 1, feedback_gain, integrator, substep_angle, secondary)
    errors = _errors(trace)
    metrics = _batch_metrics(task, trace, errors, objective).item(0)
    options = PlanOptions(feedback_gain, objective, secondary, position_tolerance, attitude_tolerance)
    success, message = _verdict(metrics, options)
    return PlanResult(
        inverse=make_inverse(inverse.name, **inverse.params()),
        options=options,
        t=trace.t,
        q=trace.q[0],
        qd=trace.qd[0],
        base_position=trace.base_position[0],
        base_attitude=trace.base_attitude[0],
        ee_position=trace.ee_position[0],
        ee_attitude=trace.ee_attitude[0],
        ee_position_desired=errors.p_des,
        ee_attitude_desired=errors.A_des,
        ee_twist_desired=task.desired_twist(trace.t),
        position_error=errors.position[0],
        attitude_error=errors.attitude[0],
        singular_values=trace.singular_values[0],
        det_J_g=trace.det_J_g[0],
        damping=trace.damping[0],
        joint_accelerations=np.full_like(trace.q[0], np.nan),  # the oracle plans kinematics only
        joint_torques=np.full_like(trace.q[0], np.nan),
        mount_force=np.full((trace.t.shape[0], 3), np.nan),
        mount_torque=np.full((trace.t.shape[0], 3), np.nan),
        clearance=np.full(trace.t.shape[0], np.nan),  # nor geometry
        clearance_pair=(None,) * trace.t.shape[0],
        metrics=metrics,
        success=success,
        message=message,
        task=task,
    )
