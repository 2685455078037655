"""Tracking metrics and the paper's objective (eqs. 17-19), batched over plans.

``B = w1 dp + w2 dp_phi + P_l``: ``dp`` is the end-effector position error (m), aggregated over
the path (``max`` by default, ``rms`` or ``final``: the paper does not say which); ``P_l`` is
+inf when any commanded joint speed exceeds the limit, else 0. The attitude term ``dp_phi`` has
two readings (``attitude_term``):

- ``"angle"`` (default): the attitude error as a rotation angle (rad), frame independent.
- ``"eq18"``: eq. 18 as printed, ``sqrt(sum_i (dp_i dphi_i)^2)`` (m rad), the products of the
  position error components and the attitude error components (the rotation vector of
  ``A A_d^T``, world axes). With it the tuned objectives of the paper's task come out at the
  paper's magnitude (about 0.003 for DLS and 0.002 for the adaptive damping).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from engine.errors import ParameterError
from engine.spatial import FloatArray

Aggregation = Literal["max", "rms", "final"]
AGGREGATIONS: tuple[str, ...] = ("max", "rms", "final")
ATTITUDE_TERMS: tuple[str, ...] = ("angle", "eq18")


@dataclass(frozen=True)
class Metrics:
    """Metrics of one plan. Errors in m and rad, speeds in rad/s, times in s."""

    position_error_max: float
    position_error_rms: float
    position_error_final: float
    attitude_error_max: float
    attitude_error_rms: float
    attitude_error_final: float
    coupled_error_max: float  # eq. 18 as printed, m rad
    coupled_error_rms: float
    coupled_error_final: float
    max_joint_speed: float
    max_joint_speed_joint: int  # 0-based joint index
    joint_speed_limit: float
    joint_speed_limit_respected: bool
    min_singular_value: float
    time_of_min_singular_value: float
    min_abs_det_J_g: float  # nan when the GJM is not square
    time_of_min_abs_det_J_g: float
    objective_b: float  # inf when the speed limit is broken or the plan diverged
    weights: tuple[float, float]
    aggregation: str
    attitude_term: str
    finite: bool  # every sample finite (the plan did not diverge)

    @property
    def max_joint_speed_deg_s(self) -> float:
        return math.degrees(self.max_joint_speed)

    def as_dict(self) -> dict[str, float | int | bool | str | tuple[float, float]]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class BatchMetrics:
    """The fields of :class:`Metrics` as ``(B,)`` arrays (weights and aggregation shared)."""

    position_error_max: FloatArray
    position_error_rms: FloatArray
    position_error_final: FloatArray
    attitude_error_max: FloatArray
    attitude_error_rms: FloatArray
    attitude_error_final: FloatArray
    coupled_error_max: FloatArray
    coupled_error_rms: FloatArray
    coupled_error_final: FloatArray
    max_joint_speed: FloatArray
    max_joint_speed_joint: np.ndarray
    joint_speed_limit: float
    joint_speed_limit_respected: np.ndarray
    min_singular_value: FloatArray
    time_of_min_singular_value: FloatArray
    min_abs_det_J_g: FloatArray
    time_of_min_abs_det_J_g: FloatArray
    objective_b: FloatArray
    weights: tuple[float, float]
    aggregation: str
    attitude_term: str
    finite: np.ndarray

    def __len__(self) -> int:
        return int(self.objective_b.shape[0])

    def item(self, i: int) -> Metrics:
        values = {}
        for f in fields(Metrics):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = v[i].item()
            values[f.name] = v
        return Metrics(**values)


def aggregate(errors: FloatArray, aggregation: str) -> FloatArray:
    """Aggregate ``errors (B, N+1)`` over time: ``max``, ``rms`` or ``final``."""
    if aggregation == "max":
        return np.max(errors, axis=-1)
    if aggregation == "rms":
        return np.sqrt(np.mean(errors**2, axis=-1))
    if aggregation == "final":
        return errors[..., -1]
    raise ParameterError("aggregation", f"must be one of {', '.join(AGGREGATIONS)}")


def check_weights(weights: Sequence[float]) -> tuple[float, float]:
    w = tuple(float(x) for x in weights)
    if len(w) != 2 or not all(math.isfinite(x) and x >= 0.0 for x in w) or sum(w) <= 0.0:
        raise ParameterError("weights", "expected two finite numbers >= 0, not both zero")
    return (w[0], w[1])


def check_attitude_term(attitude_term: str) -> str:
    if attitude_term not in ATTITUDE_TERMS:
        raise ParameterError("attitude_term", f"must be one of {', '.join(ATTITUDE_TERMS)}")
    return attitude_term


@dataclass(frozen=True)
class Objective:
    """How ``B`` is formed: weights ``(w1, w2)``, aggregation over the path, attitude term."""

    weights: tuple[float, float] = (0.5, 0.5)
    aggregation: str = "max"
    attitude_term: str = "angle"

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", check_weights(self.weights))
        if self.aggregation not in AGGREGATIONS:
            raise ParameterError("aggregation", f"must be one of {', '.join(AGGREGATIONS)}")
        check_attitude_term(self.attitude_term)


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
) -> BatchMetrics:
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
    return BatchMetrics(
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
    )
