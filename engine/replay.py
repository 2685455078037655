"""Independent replay of a plan: the stand-in for the paper's ADAMS run.

The planned joint motion (``q_k`` with constant ``qd_k`` over each step) is replayed and the
base motion integrated with an error-controlled DOP853 integrator, step by step, in compiled
code (:mod:`engine.kernels.replay`). The base velocity comes from the textbook 6x6 momentum
equations ``H_b [v_0; w_0] + H_bm qd = 0`` (Umetani and Yoshida 1989) built body by body, a
different formulation from the planner's reduced 3x3 one; the base attitude is integrated as a
unit quaternion, the base position as a state (not from the fixed CoM, so CoM drift is a check).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from engine.kernels import replay as replay_kernels
from engine.model import RobotModel
from engine.planner import PlanResult
from engine.spatial import FloatArray, matrix_to_quaternion, rotation_angle

RTOL = 1e-11
ATOL = 1e-13

#: Why a compiled integration stopped, by its status (for messages; :mod:`engine.executed` too).
FAILURES = {
    replay_kernels.STEP_TOO_SMALL: "the step size fell below the resolution of the time axis",
    replay_kernels.TOO_MANY_STEPS: f"more than {replay_kernels.MAX_STEPS_PER_INTERVAL} integration steps in one plan step",
    replay_kernels.SINGULAR: "the base inertia matrix H_b is singular",
}


@dataclass(frozen=True)
class ReplayResult:
    """Replayed motion and its checks; arrays have the plan's ``N + 1`` samples."""

    t: FloatArray
    ee_position: FloatArray  # (N+1, 3) m, achieved
    ee_attitude: FloatArray  # (N+1, 3, 3)
    base_position: FloatArray  # (N+1, 3) m
    base_attitude: FloatArray  # (N+1, 3, 3)
    path_position_error_max: float  # m, achieved vs desired path
    path_position_error_final: float
    path_attitude_error_max: float  # rad
    path_attitude_error_final: float
    plan_gap_position_max: float  # m, planned vs replayed end effector
    plan_gap_attitude_max: float  # rad
    base_attitude_gap_max: float  # rad, planned vs replayed base attitude
    linear_momentum_residual_max: float  # N s
    angular_momentum_residual_max: float  # N m s
    com_drift_max: float  # m
    n_function_evaluations: int
    success: bool
    message: str


def failed_result(t: FloatArray, message: str, nfev: int = 0) -> ReplayResult:
    """A replay that could not run (``message`` says why): every sample and check NaN."""
    nan = float("nan")
    n_samples = t.shape[0]
    vectors = np.full((n_samples, 3), nan)
    matrices = np.full((n_samples, 3, 3), nan)
    checks = {f.name: nan for f in fields(ReplayResult) if f.type == "float"}
    return ReplayResult(
        t=t,
        ee_position=vectors,
        ee_attitude=matrices,
        base_position=vectors.copy(),
        base_attitude=matrices.copy(),
        n_function_evaluations=nfev,
        success=False,
        message=message,
        **checks,
    )


def replay(model: RobotModel, plan_result: PlanResult, *, rtol: float = RTOL, atol: float = ATOL) -> ReplayResult:
    """Replay ``plan_result``'s joint motion and integrate the base (DOP853, ``rtol``/``atol``)."""
    t = np.ascontiguousarray(plan_result.t, dtype=float)
    q = np.ascontiguousarray(plan_result.q, dtype=float)
    qd = np.ascontiguousarray(plan_result.qd, dtype=float)
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
        return failed_result(t, "the plan is not finite, nothing to replay")
    n_samples = t.shape[0]
    ys = np.empty((n_samples, 7))
    ys[0, :3] = plan_result.base_position[0]
    ys[0, 3:] = matrix_to_quaternion(plan_result.base_attitude[0])
    status, failed_step, nfev = replay_kernels.integrate(model.chain, t, q, qd, ys, float(rtol), float(atol))
    if status != replay_kernels.OK:
        return failed_result(t, f"replay integration failed at t = {t[failed_step]:g} s: {FAILURES[status]}", int(nfev))

    ee_p = np.empty((n_samples, 3))
    ee_A = np.empty((n_samples, 3, 3))
    base_A = np.empty((n_samples, 3, 3))
    lin_res = np.empty(n_samples)
    ang_res = np.empty(n_samples)
    com = np.empty((n_samples, 3))
    replay_kernels.evaluate_samples(model.chain, q, qd, ys, ee_p, ee_A, base_A, lin_res, ang_res, com)

    return summarise(plan_result, ys[:, :3].copy(), ee_p, ee_A, base_A, lin_res, ang_res, com, int(nfev))


def summarise(
    plan_result: PlanResult,
    base_p: FloatArray,
    ee_p: FloatArray,
    ee_A: FloatArray,
    base_A: FloatArray,
    lin_res: FloatArray,
    ang_res: FloatArray,
    com: FloatArray,
    nfev: int,
) -> ReplayResult:
    """The replay's result from its samples (``(N+1, ...)``, the replayed poses, momentum
    residuals and system CoM): its path errors against the desired path and its gaps to the
    plan."""
    pos_err = np.linalg.norm(ee_p - plan_result.ee_position_desired, axis=-1)
    att_err = rotation_angle(np.swapaxes(plan_result.ee_attitude_desired, -1, -2) @ ee_A)
    gap_p = np.linalg.norm(ee_p - plan_result.ee_position, axis=-1)
    gap_A = rotation_angle(np.swapaxes(plan_result.ee_attitude, -1, -2) @ ee_A)
    gap_base = rotation_angle(np.swapaxes(plan_result.base_attitude, -1, -2) @ base_A)
    return ReplayResult(
        t=plan_result.t,
        ee_position=ee_p,
        ee_attitude=ee_A,
        base_position=base_p,
        base_attitude=base_A,
        path_position_error_max=float(pos_err.max()),
        path_position_error_final=float(pos_err[-1]),
        path_attitude_error_max=float(att_err.max()),
        path_attitude_error_final=float(att_err[-1]),
        plan_gap_position_max=float(gap_p.max()),
        plan_gap_attitude_max=float(gap_A.max()),
        base_attitude_gap_max=float(gap_base.max()),
        linear_momentum_residual_max=float(lin_res.max()),
        angular_momentum_residual_max=float(ang_res.max()),
        com_drift_max=float(np.linalg.norm(com - com[0], axis=-1).max()),
        n_function_evaluations=nfev,
        success=True,
        message="ok",
    )
