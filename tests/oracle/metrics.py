"""Test oracle: the former numpy metrics of the engine, aggregated from per-sample series (see
:mod:`engine.metrics` for the objective B of eqs. 17-19)."""

from __future__ import annotations

import numpy as np
from oracle.spatial import FloatArray

from engine.errors import ParameterError
from engine.metrics import AGGREGATIONS, Column, Metrics, Objective


def aggregate(errors: FloatArray, aggregation: str) -> FloatArray:
    """Aggregate ``errors (B, N+1)`` over time: ``max``, ``rms`` or ``final``."""
    if aggregation == "max":
        return np.max(errors, axis=-1)
    if aggregation == "rms":
        return np.sqrt(np.mean(errors**2, axis=-1))
    if aggregation == "final":
        return errors[..., -1]
    raise ParameterError("aggregation", f"must be one of {', '.join(AGGREGATIONS)}")


def objective(
    position_errors: FloatArray,
    attitude_errors: FloatArray,
    speed_ok: np.ndarray,
    settings: Objective,
) -> FloatArray:
    """The paper's ``B`` per plan ``(B,)`` from per-sample position errors and the attitude term
    chosen by ``settings`` ``(B, N+1)``; +inf where the speed limit is broken or errors are not
    finite."""
    w1, w2 = settings.weights
    b = w1 * aggregate(position_errors, settings.aggregation) + w2 * aggregate(attitude_errors, settings.aggregation)
    return np.where(speed_ok & np.isfinite(b), b, np.inf)


def compute_metrics(
    t: FloatArray,
    position_errors: FloatArray,
    attitude_errors: FloatArray,
    coupled_errors: FloatArray,
    joint_speed_peak: FloatArray,
    sigma_min: FloatArray,
    abs_det: FloatArray,
    joint_speed_limit: float,
    settings: Objective,
) -> Metrics[Column]:
    """Metrics of ``B`` plans from per-sample series ``(B, N+1)`` (position error m, attitude
    angle rad, eq. 18 coupled error m rad) and per-joint peak speeds ``joint_speed_peak (B, n)``
    (rad/s, absolute); ``settings`` says how ``B`` is formed."""
    finite = (
        np.all(np.isfinite(position_errors), axis=-1)
        & np.all(np.isfinite(attitude_errors), axis=-1)
        & np.all(np.isfinite(joint_speed_peak), axis=-1)
    )
    peak = np.where(np.isfinite(joint_speed_peak), joint_speed_peak, np.inf)
    max_speed = np.max(peak, axis=-1)
    speed_ok = finite & (max_speed <= joint_speed_limit)
    # Non-finite samples never count as the minimum.
    sigma = np.where(np.isfinite(sigma_min), sigma_min, np.inf)
    det = np.where(np.isfinite(abs_det), abs_det, np.inf)
    i_sigma = np.argmin(sigma, axis=-1)
    i_det = np.argmin(det, axis=-1)
    rows = np.arange(position_errors.shape[0])
    square = bool(np.any(np.isfinite(abs_det)))
    none = np.full(rows.shape, -1)
    return Metrics[Column](
        position_error_max=aggregate(position_errors, "max"),
        position_error_rms=aggregate(position_errors, "rms"),
        position_error_final=aggregate(position_errors, "final"),
        attitude_error_max=aggregate(attitude_errors, "max"),
        attitude_error_rms=aggregate(attitude_errors, "rms"),
        attitude_error_final=aggregate(attitude_errors, "final"),
        coupled_error_max=aggregate(coupled_errors, "max"),
        coupled_error_rms=aggregate(coupled_errors, "rms"),
        coupled_error_final=aggregate(coupled_errors, "final"),
        max_joint_speed=max_speed,
        max_joint_speed_joint=np.argmax(peak, axis=-1),
        joint_speed_limit=float(joint_speed_limit),
        joint_speed_limit_respected=speed_ok,
        min_singular_value=sigma[rows, i_sigma],
        time_of_min_singular_value=t[i_sigma],
        min_abs_det_J_g=det[rows, i_det] if square else np.full(rows.shape, np.nan),
        time_of_min_abs_det_J_g=t[i_det] if square else np.full(rows.shape, np.nan),
        objective_b=objective(
            position_errors, attitude_errors if settings.attitude_term == "angle" else coupled_errors, speed_ok, settings
        ),
        weights=settings.weights,
        aggregation=settings.aggregation,
        attitude_term=settings.attitude_term,
        finite=finite,
        time_diverged=np.full(rows.shape, np.nan),
        max_linear_joint_speed=np.zeros(rows.shape),
        max_linear_joint_speed_joint=none,
        linear_joint_speed_limit=float("inf"),
        position_limits_respected=np.ones(rows.shape, dtype=bool),
        position_limit_joint=none,
        time_position_limit_left=np.full(rows.shape, np.nan),
        position_limit_excess=np.full(rows.shape, np.nan),
        base_rotation_max=np.full(rows.shape, np.nan),
        base_rotation_final=np.full(rows.shape, np.nan),
        max_joint_torque=np.full(rows.shape, np.nan),  # the oracle plans kinematics only
        max_joint_torque_joint=none,
        max_joint_force=np.full(rows.shape, np.nan),
        max_joint_force_joint=none,
        joint_torque_limit_respected=np.ones(rows.shape, dtype=bool),
        torque_limit_joint=none,
        time_torque_limit_exceeded=np.full(rows.shape, np.nan),
        torque_limit_peak=np.full(rows.shape, np.nan),
        dynamics_computed=np.zeros(rows.shape),
        min_clearance=np.full(rows.shape, np.nan),  # the oracle plans without geometry
        min_clearance_pair=np.full(rows.shape, None, dtype=object),
        time_of_min_clearance=np.full(rows.shape, np.nan),
        clearance_respected=np.ones(rows.shape, dtype=bool),
        clearance_broken_pair=np.full(rows.shape, None, dtype=object),
        time_collision=np.full(rows.shape, np.nan),
        collision_distance=np.full(rows.shape, np.nan),
        min_clearance_pair_index=none,
        collision_pair=none,
        geometry_checked=np.zeros(rows.shape),
        clearance=0.0,
        tracks="pose",
    )
