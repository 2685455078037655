"""Tracking metrics and the paper's objective (eqs. 17-19), batched over plans.

``B = w1 dp + w2 dp_phi + P_l``: ``dp`` is the end-effector position error (m), aggregated over
the path (``max`` by default, ``rms`` or ``final``: the paper does not say which); ``P_l`` is
+inf when any commanded joint speed exceeds its limit (rad/s for revolute joints, m/s for
prismatic ones), a joint leaves its position limits, a joint's torque (force) along the
executed trajectory exceeds the robot's effort limit or two shapes come closer than the task's
clearance (:mod:`engine.geometry`), else 0. A task that tracks the position
only has no attitude term (its attitude is not followed). The attitude term ``dp_phi`` has
two readings (``attitude_term``):

- ``"eq18"`` (default): eq. 18 as printed, ``sqrt(sum_i (dp_i dphi_i)^2)`` (m rad), the
  products of the position error components and the attitude error components (the rotation
  vector of ``A A_d^T``, world axes). With it the tuned objectives of the paper's task come out
  at the paper's magnitude (about 0.003 for DLS and 0.002 for the adaptive damping) and the
  tuned adaptive damping beats the tuned DLS by the paper's margin (about 27-30 %): the
  default, so that the paper's comparison reproduces as published.
- ``"angle"``: the attitude error as a rotation angle (rad), frame independent. Dimensionally
  cleaner (m + rad), but the attitude term then dominates ``B`` and the margin of the adaptive
  damping over DLS shrinks to a few per cent on the paper's task.

The metrics layout is declared once, here: each field of :class:`Metrics` carries its SI unit,
its slot in the planner kernel's metrics vector (:mod:`engine.kernels.plan`) if the kernel
accumulates it, and its API name, conversion, type and description (:func:`metric`). The service's
response model, its conversion and the web page's rows are derived from :data:`LAYOUT`, so a new
metric is its kernel slot and its field here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Generic, Literal, NamedTuple, TypeAlias, TypeVar

import numpy as np

from engine.errors import ParameterError
from engine.kernels import plan as kp
from engine.spatial import FloatArray

Aggregation = Literal["max", "rms", "final"]
AGGREGATIONS: tuple[str, ...] = ("max", "rms", "final")
ATTITUDE_TERMS: tuple[str, ...] = ("eq18", "angle")

#: The units of the GJM's singular values (it maps joint rates, rad/s, to [v (m/s); w (rad/s)]:
#: m/rad on the linear rows, 1 on the angular rows).
SINGULAR_VALUE_UNITS = "in the units of the GJM's singular values"
#: The unit of the GJM's determinant (and of the product of its singular values): of a revolute
#: column, the linear rows in m (m/s per rad/s) and the angular rows without unit; of a prismatic
#: column, the linear rows without unit and the angular rows in rad/m.
DET_UNITS = (
    "m^3 for revolute joints (three rows in m per rad, three without unit; each prismatic joint's column changes "
    "it by 1/m, its linear rows being without unit)"
)
NULL_NOT_FINITE = "null if not finite"

#: How a value is shown by the API: as it is (SI), in degrees, or as a 1-based joint number.
ApiConversion = Literal["", "deg", "joint"]
#: The API's type of a value: a number, a flag, a joint number, a pair of shape owners' names or
#: one of the engine's vocabularies.
ApiType = Literal["number", "bool", "joint", "pair", "attitude_term", "tracks"]
REQUIRED: Any = ...  # an API field every stored plan has


class WebRow(NamedTuple):
    """A row of the plan page's metrics card: label, unit shown, scale from the API's value
    (``None``: a yes/no flag)."""

    label: str
    unit: str
    scale: float | None


class MetricSpec(NamedTuple):
    """One entry of the metrics layout (see the module docstring)."""

    name: str  # the field of Metrics
    unit: str  # SI unit inside the engine ("" without unit)
    slot: int | None  # index in the kernel's metrics vector; None if derived after the kernel
    api: str | None  # the API's name; None if not in the API
    conversion: ApiConversion
    api_type: ApiType
    api_default: Any  # REQUIRED, or the value a plan stored before the field existed reads as
    description: str  # the API's description
    web: WebRow | None


def metric(
    unit: str,
    description: str = "",
    *,
    slot: int | None = None,
    api: str | None = None,
    conversion: ApiConversion = "",
    api_type: ApiType = "number",
    api_default: Any = REQUIRED,
    web: WebRow | None = None,
) -> Any:
    """A :class:`Metrics` field with its layout entry as metadata."""
    return field(
        metadata={
            "spec": dict(
                unit=unit,
                slot=slot,
                api=api,
                conversion=conversion,
                api_type=api_type,
                api_default=api_default,
                description=description,
                web=web,
            )
        }
    )


#: A batch of values, one per plan.
Column: TypeAlias = "np.ndarray[Any, Any]"
V = TypeVar("V", float, Column)
DEG = 180.0 / math.pi


@dataclass(frozen=True)
class Metrics(Generic[V]):
    """Metrics of plans: ``Metrics[float]`` for one plan, ``Metrics[Column]`` for a batch
    (every per-plan field a ``(B,)`` array; the settings shared). Errors in m and rad, speeds in
    rad/s (m/s for prismatic joints), times in s; joint indices 0-based (-1: none)."""

    objective_b: V = metric(
        "",
        "objective B = w1 * position term (m) + w2 * attitude term (rad, or m rad with `eq18`), with the plan's "
        "aggregation; null (eq. 19's P_l) when a joint speed, joint position or torque limit or the clearance is "
        "broken, or the plan diverged",
        api="objective_b",
        web=WebRow("objective B", "", 1.0),
    )
    position_error_max: V = metric(
        "m",
        f"largest end-effector position error, m; {NULL_NOT_FINITE}",
        slot=kp.POS_MAX,
        api="position_error_max_m",
        web=WebRow("max position error", "mm", 1e3),
    )
    position_error_rms: V = metric(
        "m",
        f"root mean square position error, m; {NULL_NOT_FINITE}",
        slot=kp.POS_RMS,
        api="position_error_rms_m",
        web=WebRow("RMS position error", "mm", 1e3),
    )
    position_error_final: V = metric(
        "m",
        f"position error at the end, m; {NULL_NOT_FINITE}",
        slot=kp.POS_FINAL,
        api="position_error_final_m",
        web=WebRow("final position error", "mm", 1e3),
    )
    attitude_error_max: V = metric(
        "rad",
        f"largest attitude error (rotation angle), rad; {NULL_NOT_FINITE}",
        slot=kp.ATT_MAX,
        api="attitude_error_max_rad",
        web=WebRow("max attitude error", "deg", DEG),
    )
    attitude_error_rms: V = metric(
        "rad",
        f"root mean square attitude error, rad; {NULL_NOT_FINITE}",
        slot=kp.ATT_RMS,
        api="attitude_error_rms_rad",
        web=WebRow("RMS attitude error", "deg", DEG),
    )
    attitude_error_final: V = metric(
        "rad",
        f"attitude error at the end, rad; {NULL_NOT_FINITE}",
        slot=kp.ATT_FINAL,
        api="attitude_error_final_rad",
        web=WebRow("final attitude error", "deg", DEG),
    )
    coupled_error_max: V = metric(
        "m rad",
        "eq. 18 as printed, sqrt(sum (dp_i dphi_i)^2), largest, m rad; null if not finite",
        slot=kp.CPL_MAX,
        api="coupled_error_max_m_rad",
        api_default=None,
    )
    coupled_error_rms: V = metric(
        "m rad",
        "eq. 18 as printed, root mean square, m rad",
        slot=kp.CPL_RMS,
        api="coupled_error_rms_m_rad",
        api_default=None,
    )
    coupled_error_final: V = metric(
        "m rad",
        "eq. 18 as printed, at the end, m rad",
        slot=kp.CPL_FINAL,
        api="coupled_error_final_m_rad",
        api_default=None,
    )
    attitude_term: str = metric(
        "",
        "the attitude term B was formed with (plans stored before it was recorded: `angle`)",
        api="attitude_term",
        api_type="attitude_term",
        api_default="angle",
    )
    max_joint_speed: V = metric(
        "rad/s",
        f"largest speed of any revolute joint, deg/s; {NULL_NOT_FINITE}",
        slot=kp.MAX_SPEED,
        api="max_joint_speed_deg_s",
        conversion="deg",
        web=WebRow("max joint speed", "deg/s", 1.0),
    )
    joint_speed_limit: float = metric(
        "rad/s",
        "the task's revolute joint speed limit, deg/s",
        api="joint_speed_limit_deg_s",
        conversion="deg",
        api_default=None,
        web=WebRow("joint speed limit", "deg/s", 1.0),
    )
    joint_speed_limit_respected: V = metric(
        "",
        "every joint within its speed limit at every sample",
        api="joint_speed_limit_respected",
        api_type="bool",
        web=WebRow("speed limit respected", "", None),
    )
    min_singular_value: V = metric(
        "",
        f"smallest singular value of the GJM along the plan, {SINGULAR_VALUE_UNITS}; {NULL_NOT_FINITE}",
        slot=kp.MIN_SIGMA,
        api="min_singular_value",
        web=WebRow("min singular value σ_min", "SI, mixed units", 1.0),
    )
    time_of_min_singular_value: V = metric(
        "s",
        "when the smallest singular value occurred, s",
        slot=kp.T_MIN_SIGMA,
        api="time_of_min_singular_value_s",
        web=WebRow("time of min σ_min", "s", 1.0),
    )
    min_abs_det_J_g: V = metric(
        "",
        f"smallest |det| of the tracked rows of the GJM along the plan, {DET_UNITS} for a pose task; null unless "
        "they are square, or if not finite",
        slot=kp.MIN_DET,
        api="min_abs_det_gjm",
        web=WebRow("min |det J_g|", "", 1.0),
    )
    time_of_min_abs_det_J_g: V = metric(
        "s",
        "when the smallest |det| occurred, s",
        slot=kp.T_MIN_DET,
        api="time_of_min_abs_det_gjm_s",
        web=WebRow("time of min |det J_g|", "s", 1.0),
    )
    tracks: str = metric(
        "",
        "what the plan followed: the whole `pose` or the `position`",
        api="tracks",
        api_type="tracks",
        api_default="pose",
    )
    max_linear_joint_speed: V = metric(
        "m/s",
        f"largest speed of any prismatic joint, m/s (0 without any); {NULL_NOT_FINITE}",
        slot=kp.MAX_LIN_SPEED,
        api="max_linear_joint_speed_m_s",
        api_default=None,
    )
    linear_joint_speed_limit: float = metric(
        "m/s", "the task's prismatic joint speed limit, m/s; null: none", api="joint_speed_limit_m_s", api_default=None
    )
    position_limits_respected: V = metric(
        "",
        "every joint within its position limits at every sample (null: a plan stored before limits were checked)",
        api="position_limits_respected",
        api_type="bool",
        api_default=None,
    )
    position_limit_joint: V = metric(
        "",
        "the first joint (1-based index) found outside its limits; null if none",
        slot=kp.LIMIT_JOINT,
        api="position_limit_joint",
        conversion="joint",
        api_type="joint",
        api_default=None,
    )
    time_position_limit_left: V = metric(
        "s",
        "when that joint left its limits, s; null if none",
        slot=kp.T_LIMIT,
        api="time_position_limit_left_s",
        api_default=None,
    )
    base_rotation_max: V = metric(
        "rad",
        f"the carrier's largest rotation from its start, rad; {NULL_NOT_FINITE}",
        slot=kp.BASE_ROT_MAX,
        api="base_attitude_change_max_rad",
        api_default=None,
    )
    base_rotation_final: V = metric(
        "rad",
        f"the carrier's rotation from its start at the end, rad; {NULL_NOT_FINITE}",
        slot=kp.BASE_ROT_FINAL,
        api="base_attitude_change_final_rad",
        api_default=None,
    )
    max_joint_torque: V = metric(
        "N m",
        "largest |torque| of any revolute joint along the executed trajectory (the clamped cubic spline through the "
        "samples), N m; null if not computed (a diverged plan, or a plan stored before torques were)",
        slot=kp.MAX_TORQUE,
        api="max_joint_torque_n_m",
        api_default=None,
        web=WebRow("max joint torque", "N m", 1.0),
    )
    max_joint_force: V = metric(
        "N",
        "largest |force| of any prismatic joint along the executed trajectory, N (0 without any); null if not computed",
        slot=kp.MAX_FORCE,
        api="max_joint_force_n",
        api_default=None,
    )
    joint_torque_limit_respected: V = metric(
        "",
        "every joint's torque (force) within the robot's effort limit at every sample (true without limits; null: a "
        "plan stored before torques were checked)",
        api="joint_torque_limit_respected",
        api_type="bool",
        api_default=None,
        web=WebRow("torque limit respected", "", None),
    )
    torque_limit_joint: V = metric(
        "",
        "the first joint (1-based index) found over its torque (force) limit; null if none",
        slot=kp.EFFORT_JOINT,
        api="torque_limit_joint",
        conversion="joint",
        api_type="joint",
        api_default=None,
    )
    time_torque_limit_exceeded: V = metric(
        "s",
        "when that joint first exceeded its limit, s; null if none",
        slot=kp.T_EFFORT,
        api="time_torque_limit_exceeded_s",
        api_default=None,
    )
    min_clearance: V = metric(
        "m",
        "the smallest distance between any two shapes that are checked (links, carrier, obstacles), at the samples and "
        "between them, m; negative: they overlap; null for a plan without collision geometry",
        slot=kp.MIN_CLEARANCE,
        api="min_clearance_m",
        api_default=None,
        web=WebRow("min clearance", "mm", 1e3),
    )
    min_clearance_pair: Any = metric(
        "",
        "the pair at the smallest distance: two names (a link's name, `carrier`, or `obstacle<i>` for the task's "
        "obstacle i); null without geometry",
        api="min_clearance_pair",
        api_type="pair",
        api_default=None,
    )
    time_of_min_clearance: V = metric(
        "s",
        "when the smallest distance occurred, s; null without geometry",
        slot=kp.T_MIN_CLEARANCE,
        api="t_min_clearance_s",
        api_default=None,
    )
    clearance_respected: V = metric(
        "",
        "no pair came closer than the task's `clearance_m` (true without geometry; null: a plan stored before "
        "clearances were checked)",
        api="clearance_respected",
        api_type="bool",
        api_default=None,
        web=WebRow("clearance respected", "", None),
    )
    clearance_broken_pair: Any = metric(
        "",
        "the first pair found closer than the clearance; null if none",
        api="clearance_broken_pair",
        api_type="pair",
        api_default=None,
    )
    time_collision: V = metric(
        "s",
        "when that pair was first closer than the clearance, s; null if none",
        slot=kp.T_COLLISION,
        api="t_clearance_broken_s",
        api_default=None,
    )
    collision_distance: V = metric(
        "m",
        "that pair's distance then, m (negative: overlapping; between samples, a lower bound); null if none",
        slot=kp.COLLISION_DISTANCE,
        api="clearance_broken_distance_m",
        api_default=None,
    )
    # Not in the API: the objective's settings, joint indices, divergence.
    weights: tuple[float, float] = metric("")
    aggregation: str = metric("")
    finite: V = metric("", slot=kp.FINITE)  # every sample finite (the plan did not diverge)
    time_diverged: V = metric("s", slot=kp.T_DIVERGED)  # the sample where a diverged plan stopped
    max_joint_speed_joint: V = metric("", slot=kp.MAX_SPEED_JOINT)  # 0-based
    max_linear_joint_speed_joint: V = metric("", slot=kp.MAX_LIN_SPEED_JOINT)  # 0-based, -1 without prismatic joints
    position_limit_excess: V = metric("rad or m", slot=kp.LIMIT_EXCESS)  # that joint's largest excess
    max_joint_torque_joint: V = metric("", slot=kp.MAX_TORQUE_JOINT)  # 0-based, -1 without revolute joints
    max_joint_force_joint: V = metric("", slot=kp.MAX_FORCE_JOINT)  # 0-based, -1 without prismatic joints
    torque_limit_peak: V = metric("N m or N", slot=kp.EFFORT_PEAK)  # the largest effort of torque_limit_joint
    dynamics_computed: V = metric("", slot=kp.DYNAMICS)  # the torques were computed (1.0) or not (0.0)
    min_clearance_pair_index: V = metric("", slot=kp.CLEARANCE_PAIR)  # index of the checked pairs, -1: none
    collision_pair: V = metric("", slot=kp.COLLISION_PAIR)  # the first pair below the clearance, -1: none
    geometry_checked: V = metric("", slot=kp.GEOMETRY)  # 1.0 when the plan had pairs to check
    clearance: float = metric("m")  # the task's clearance

    @property
    def max_joint_speed_deg_s(self) -> V:
        return self.max_joint_speed * DEG

    def __len__(self) -> int:
        return int(np.size(self.objective_b))

    def item(self, i: int) -> Metrics[float]:
        """Plan ``i`` of a batch."""
        values = {}
        for name in _NAMES:
            v = getattr(self, name)
            values[name] = v.item(i) if isinstance(v, np.ndarray) else v
        return Metrics(**values)  # not Metrics[float](...): the subscripted call costs a few µs

    def as_dict(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in _NAMES}


_NAMES = tuple(f.name for f in fields(Metrics))
#: The metrics layout, in the API's order (see :class:`MetricSpec`).
LAYOUT: tuple[MetricSpec, ...] = tuple(MetricSpec(f.name, **f.metadata["spec"]) for f in fields(Metrics))
_SLOTS = tuple(s for s in LAYOUT if s.slot is not None)
assert sorted(s.slot or 0 for s in _SLOTS) == list(range(kp.N_METRICS)), "every kernel slot is one field"
_INDICES = frozenset(
    {
        "max_joint_speed_joint",
        "max_linear_joint_speed_joint",
        "position_limit_joint",
        "max_joint_torque_joint",
        "max_joint_force_joint",
        "torque_limit_joint",
        "min_clearance_pair_index",
        "collision_pair",
    }
)


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
    attitude_term: str = "eq18"

    def __post_init__(self) -> None:
        object.__setattr__(self, "weights", check_weights(self.weights))
        if self.aggregation not in AGGREGATIONS:
            raise ParameterError("aggregation", f"must be one of {', '.join(AGGREGATIONS)}")
        check_attitude_term(self.attitude_term)


def objective(metrics: Metrics[Any], settings: Objective) -> FloatArray:
    """The paper's ``B`` per plan from aggregated errors: ``w1 dp + w2 dp_phi`` with the
    aggregation and attitude term of ``settings`` (``w1 dp`` alone for a position task); +inf
    where a speed, position or effort limit or the clearance is broken or the plan is not finite
    (``P_l``)."""
    w1, w2 = settings.weights
    position = np.asarray(getattr(metrics, f"position_error_{settings.aggregation}"), dtype=float)
    b = w1 * position
    if metrics.tracks == "pose":
        term = "attitude_error" if settings.attitude_term == "angle" else "coupled_error"
        b = b + w2 * np.asarray(getattr(metrics, f"{term}_{settings.aggregation}"), dtype=float)
    ok = (
        np.asarray(metrics.joint_speed_limit_respected, dtype=bool)
        & np.asarray(metrics.position_limits_respected, dtype=bool)
        & np.asarray(metrics.joint_torque_limit_respected, dtype=bool)
        & np.asarray(metrics.clearance_respected, dtype=bool)
        & np.isfinite(b)
    )
    result: FloatArray = np.where(ok, b, np.inf)
    return result


def batch_metrics(
    raw: FloatArray,
    joint_speed_limit: float,
    settings: Objective,
    *,
    linear_joint_speed_limit: float = math.inf,
    tracks: str = "pose",
    clearance: float = 0.0,
    pair_names: Sequence[tuple[str, str]] = (),
) -> Metrics[Column]:
    """Metrics of ``B`` plans from the planner kernel's metrics rows ``raw (B, N_METRICS)``
    (:mod:`engine.kernels.plan`); ``settings`` say how ``B`` is formed, ``tracks`` what the
    plans followed, ``clearance`` (m) and ``pair_names`` (the owners of each checked pair) what
    their geometry was."""
    cols = raw.T.copy()  # one copy: each metric's column a contiguous row of its own
    values: dict[str, Any] = {
        s.name: cols[s.slot].astype(int) if s.name in _INDICES else cols[s.slot] for s in _SLOTS if s.slot is not None
    }
    finite = cols[kp.FINITE] > 0.5
    values["finite"] = finite
    values["joint_speed_limit_respected"] = (
        finite & (cols[kp.MAX_SPEED] <= joint_speed_limit) & (cols[kp.MAX_LIN_SPEED] <= linear_joint_speed_limit)
    )
    values["position_limits_respected"] = values["position_limit_joint"] < 0
    values["joint_torque_limit_respected"] = finite & (values["torque_limit_joint"] < 0)
    values["clearance_respected"] = values["collision_pair"] < 0

    def names(indices: np.ndarray) -> np.ndarray:
        out = np.empty(indices.shape[0], dtype=object)
        out[:] = [pair_names[i] if i >= 0 else None for i in indices.tolist()]
        return out

    values["min_clearance_pair"] = names(values["min_clearance_pair_index"])
    values["clearance_broken_pair"] = names(values["collision_pair"])
    values.update(
        objective_b=np.empty(raw.shape[0]),
        joint_speed_limit=float(joint_speed_limit),
        linear_joint_speed_limit=float(linear_joint_speed_limit),
        weights=settings.weights,
        aggregation=settings.aggregation,
        attitude_term=settings.attitude_term,
        tracks=tracks,
        clearance=float(clearance),
    )
    result: Metrics[Column] = Metrics(**values)
    result.objective_b[:] = objective(result, settings)
    return result
