"""Plans: the request, its metrics, trajectory and replay, and the shortest feasible duration."""

from __future__ import annotations

import math
from datetime import datetime
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import ConfigDict, Field, create_model

from engine import DurationSearch, Objective, PlanOptions, ReplayResult
from engine.metrics import LAYOUT, REQUIRED, Metrics, MetricSpec
from engine.shortest import DEFAULT_RELATIVE_TOLERANCE
from engine.trajectory import MAX_DURATION_S
from service.schemas.common import (
    AGGREGATION_DESCRIPTION,
    DET_UNITS,
    ID_PATTERN,
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    SINGULAR_VALUE_UNITS,
    AggregationName,
    AttitudeTerm,
    AttitudeTermName,
    Input,
    Output,
    TrackedQuantity,
    Weights,
    _not_required,
    vocabulary,
)
from service.schemas.methods import MethodIn, MethodOut, SecondaryIn
from service.schemas.paths import PathSchema
from service.schemas.robots import OneRobot, RobotParams
from service.schemas.tasks import TaskIn
from service.schemas.uncertainty import RobustnessOut, UncertaintyIn

if TYPE_CHECKING:
    PathTypeName = str
else:
    PathTypeName = vocabulary("PathType", PathSchema.types)


class PlanRequest(OneRobot):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "task": PAPER_TASK_EXAMPLE,
                    "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
                    "feedback_gain": 0.0,
                    "aggregation": "max",
                    "weights": [0.5, 0.5],
                    "replay": True,
                }
            ]
        },
    )

    task: TaskIn = Field(description="the Cartesian task")
    method: MethodIn = Field(default_factory=MethodIn, description="the robust inverse (default: adaptive damping)")
    feedback_gain: float = Field(
        default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback added to the path twist"
    )
    aggregation: AggregationName = Field(default="max", description=AGGREGATION_DESCRIPTION)
    weights: Weights = [0.5, 0.5]  # noqa: RUF012 (a pydantic field: copied per instance)
    attitude_term: AttitudeTerm = "eq18"
    replay: bool = Field(
        default=True,
        description="replay the plan independently (its joint motion re-integrated through the momentum equations by a "
        "compiled DOP853) and report the gaps",
    )
    secondary: SecondaryIn | None = Field(default=None, description="a null-space objective for a redundant arm")
    uncertainty: UncertaintyIn | None = Field(
        default=None,
        description="plan it also on robots sampled within these bounds of the mass properties and the start, open and "
        "closed loop (`robustness` in the answer); null: the nominal robot only",
    )

    def options(self) -> PlanOptions:
        """The engine's plan options of this request (feedback gain, objective, secondary objective)."""
        return PlanOptions(
            feedback_gain=self.feedback_gain,
            objective=Objective((self.weights[0], self.weights[1]), self.aggregation, self.attitude_term),
            secondary=self.secondary.to_engine() if self.secondary is not None else None,
        )


def _patch_of(model: type[Input], name: str) -> Any:
    """A merge patch of ``model``: its fields, each optional and of any JSON value (a value is
    checked once merged, as part of the whole request), no other field."""
    fields: dict[str, Any] = {
        info.alias or attr: (Any, Field(default=None, description=f"{info.description or attr}; a merge patch member"))
        for attr, info in model.model_fields.items()
    }
    return create_model(name, __base__=Input, __doc__=f"A JSON merge patch of a `{model.__name__}`.", **fields)


if TYPE_CHECKING:
    TaskPatch = Input
    MethodPatch = Input
    SecondaryPatch = Input
    UncertaintyPatch = Input
else:
    TaskPatch = _patch_of(TaskIn, "TaskPatch")
    MethodPatch = _patch_of(MethodIn, "MethodPatch")
    SecondaryPatch = _patch_of(SecondaryIn, "SecondaryPatch")
    UncertaintyPatch = _patch_of(UncertaintyIn, "UncertaintyPatch")


class PlanRerun(Input):
    """A stored plan planned again with changes: the stored plan's request (`from_plan_id`, as its
    `request` shows it) with this body's other fields merged into it as a JSON merge patch (RFC 7396):
    an object is merged member by member, recursively; any other value (a number, a list, a text)
    replaces the stored one; `null` removes the member, so the field takes its default. Two additions
    to RFC 7396: a `path` (in `task`) whose `type` differs from the stored path's, and a `method` whose
    `name` differs from the stored method's, replace the stored object whole instead of being merged
    into it (the parameters of one path type or method mean nothing to another); and `robot` (an
    inline robot) replaces the stored robot whole: giving it drops the stored `robot_id`, giving
    `robot_id` drops the stored inline `robot`. The
    merged request is then validated as any plan request (errors name its fields, `body.task...`)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"from_plan_id": "0" * 32, "method": {"params": {"epsilon": 0.37}}, "task": {"duration_s": 20.0}},
                {"from_plan_id": "0" * 32, "method": {"name": "dls", "params": {"lambda": 0.035}}, "replay": False},
            ]
        },
    )

    from_plan_id: str = Field(pattern=ID_PATTERN, description="the stored plan whose request is the starting point")
    robot_id: str | None = Field(default=None, description="another stored robot (drops the stored inline `robot`)")
    robot: RobotParams | None = Field(default=None, description="an inline robot, whole (drops the stored `robot_id`)")
    task: TaskPatch | None = Field(
        default=None,
        description="merged into the stored task (`path` by its `type`; a new path type drops the stored `duration_s`, "
        "`target_position_m` and `target_attitude_quaternion` unless this gives them)",
    )
    method: MethodPatch | None = Field(default=None, description="merged into the stored method (by its `name`)")
    feedback_gain: float | None = Field(default=None, description="replaces the stored value (1/s; null: the default)")
    aggregation: str | None = Field(default=None, description="replaces the stored value (null: the default)")
    weights: list[float] | None = Field(default=None, description="replace the stored weights (dimensionless; null: the default)")
    attitude_term: str | None = Field(default=None, description="replaces the stored value (null: the default)")
    replay: bool | None = Field(default=None, description="replaces the stored value (null: the default)")
    secondary: SecondaryPatch | None = Field(default=None, description="merged into the stored one (null: none)")
    uncertainty: UncertaintyPatch | None = Field(default=None, description="merged into the stored one (null: none)")

    def patch(self) -> dict[str, Any]:
        """The merge patch: the fields this body gives (nulls included), but ``from_plan_id``."""
        return self.model_dump(mode="json", exclude_unset=True, exclude={"from_plan_id"})


def _metric_field(spec: MetricSpec) -> tuple[Any, Any]:
    types: dict[str, Any] = {
        "number": float | None,
        "bool": bool if spec.api_default is REQUIRED else bool | None,
        "joint": int | None,
        "pair": list[str] | None,
        "attitude_term": AttitudeTermName,
        "tracks": TrackedQuantity,
    }
    if spec.api_default is REQUIRED:
        return types[spec.api_type], Field(description=spec.description)
    return types[spec.api_type], Field(default=spec.api_default, description=spec.description)


#: The metrics in the API, in the layout's order (:data:`engine.metrics.LAYOUT`).
API_METRICS: tuple[MetricSpec, ...] = tuple(spec for spec in LAYOUT if spec.api is not None)

if TYPE_CHECKING:
    PlanMetrics = Output
else:
    PlanMetrics = create_model(
        "PlanMetrics",
        __base__=Output,
        __doc__="What a plan achieved: errors along the path (world frame, against the desired pose of each sample), "
        "joint speeds and the closest approach to a singularity.",
        **{spec.api: _metric_field(spec) for spec in API_METRICS},
    )


def _api_value(spec: MetricSpec, value: Any) -> Any:
    if spec.conversion == "deg":
        # 15 significant digits: the conversion's last-bit noise off (a limit of 6 deg/s read 6.000000000000001)
        value = float(f"{math.degrees(value):.15g}") if math.isfinite(value) else value
    elif spec.conversion == "joint":
        return int(value) + 1 if value is not None and value >= 0 else None
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, tuple):  # a pair of names
        return list(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def metrics_out(metrics: Metrics[float]) -> dict[str, Any]:
    """The API's metrics of a plan (JSON-ready: numbers that are not finite are null)."""
    return {spec.api: _api_value(spec, getattr(metrics, spec.name)) for spec in API_METRICS if spec.api is not None}


#: Trajectory arrays are time-major: one row per sample of `t_s`; null where a value is not finite.
PER_SAMPLE = "one row per sample of `t_s`"
EXECUTED = "(the clamped cubic spline through the joint samples, from rest to the last commanded rate)"
NO_DYNAMICS = "null rows for a diverged plan (and for plans stored before dynamics were computed)"


class Trajectory(Output):
    """Every sample of a plan, time-major (one row per sample of `t_s`); null where a value is not
    finite (a diverged plan). Joint columns follow the robot's joints: revolute joints in the
    `_deg` arrays, prismatic ones in the `_m` arrays (null in the other's columns)."""

    model_config = ConfigDict(
        json_schema_extra=_not_required(
            "joint_displacements_m", "joint_velocities_m_s", "joint_accelerations_m_s2", "joint_forces_n", "clearance_m"
        )
    )

    t_s: list[float] = Field(description="sample times, s")
    joint_angles_deg: list[list[float | None]] = Field(
        description=f"joint angles, deg; {PER_SAMPLE}, one column per joint (null in prismatic columns)"
    )
    joint_velocities_deg_s: list[list[float | None]] = Field(
        description=f"joint rates, deg/s; {PER_SAMPLE}, one column per joint (null in prismatic columns)"
    )
    joint_displacements_m: list[list[float | None]] | None = Field(
        default=None,
        description=f"prismatic joint positions, m; {PER_SAMPLE} (null in revolute columns); only for robots with "
        "prismatic joints (left out otherwise)",
    )
    joint_velocities_m_s: list[list[float | None]] | None = Field(
        default=None,
        description=f"prismatic joint rates, m/s; {PER_SAMPLE} (null in revolute columns); only for robots with "
        "prismatic joints (left out otherwise)",
    )
    base_position_m: list[list[float | None]] = Field(description=f"base CoM position in world, m; {PER_SAMPLE}, [x, y, z]")
    base_attitude_quaternion: list[list[float | None]] = Field(
        description=f"base attitude [w, x, y, z] (base -> world); {PER_SAMPLE}"
    )
    ee_position_m: list[list[float | None]] = Field(description=f"end-effector position in world, m; {PER_SAMPLE}")
    ee_position_desired_m: list[list[float | None]] = Field(description=f"the path's position, m; {PER_SAMPLE}")
    ee_attitude_quaternion: list[list[float | None]] = Field(
        description=f"end-effector attitude [w, x, y, z] (end effector -> world); {PER_SAMPLE}"
    )
    ee_attitude_desired_quaternion: list[list[float | None]] = Field(
        description=f"the path's attitude [w, x, y, z]; {PER_SAMPLE}"
    )
    singular_values: list[list[float | None]] = Field(
        description=f"singular values of the GJM, descending, {SINGULAR_VALUE_UNITS}; {PER_SAMPLE}"
    )
    det_gjm: list[float | None] = Field(description=f"det of the GJM per sample, {DET_UNITS} (6 joints; null otherwise)")
    damping: list[list[float | None]] = Field(
        description=f"effective damping per singular direction, {SINGULAR_VALUE_UNITS} (0: undamped); {PER_SAMPLE}"
    )
    position_error_m: list[float | None] = Field(description="end-effector position error per sample, m")
    attitude_error_rad: list[float | None] = Field(description="end-effector attitude error (rotation angle) per sample, rad")
    joint_accelerations_deg_s2: list[list[float | None]] = Field(
        description=f"joint accelerations of the executed trajectory {EXECUTED}, deg/s^2; {PER_SAMPLE}, one column per "
        f"joint (null in prismatic columns); {NO_DYNAMICS}"
    )
    joint_accelerations_m_s2: list[list[float | None]] | None = Field(
        default=None,
        description=f"prismatic joint accelerations of the executed trajectory, m/s^2; {PER_SAMPLE} (null in revolute "
        "columns); only for robots with prismatic joints (left out otherwise)",
    )
    joint_torques_n_m: list[list[float | None]] = Field(
        description=f"joint torques along the executed trajectory (free-floating inverse dynamics, no gravity), N m; "
        f"{PER_SAMPLE}, one column per joint (null in prismatic columns); {NO_DYNAMICS}"
    )
    joint_forces_n: list[list[float | None]] | None = Field(
        default=None,
        description=f"prismatic joint forces along the executed trajectory, N; {PER_SAMPLE} (null in revolute columns); "
        "only for robots with prismatic joints (left out otherwise)",
    )
    mount_force_n: list[list[float | None]] = Field(
        description=f"the force the arm exerts on the carrier at joint 1, carrier frame, N; {PER_SAMPLE}, [x, y, z]; "
        f"{NO_DYNAMICS}"
    )
    mount_torque_n_m: list[list[float | None]] = Field(
        description=f"the torque the arm exerts on the carrier about joint 1's origin, carrier frame, N m; {PER_SAMPLE}, "
        f"[x, y, z]; {NO_DYNAMICS}"
    )
    clearance_m: list[float | None] | None = Field(
        default=None,
        description=f"the smallest distance between the checked pairs of shapes at each sample, m ({PER_SAMPLE}; "
        "negative: overlapping); only for plans with collision geometry (left out otherwise)",
    )

    @staticmethod
    def arrays(record: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The trajectory's arrays in the API's units (written by :mod:`service.infra.jsonio`, NaN as
        null) from a plan's SI record (:func:`service.usecases.plans.record_of`): joint angles in
        degrees, prismatic joints' columns moved to the ``_m`` arrays, attitudes as quaternions."""
        prismatic = record["prismatic"].astype(bool)
        q, qd = record["q"], record["qd"]
        unknown = np.full(q.shape, np.nan)  # a plan stored before its dynamics were computed
        qdd, tau = record.get("qdd", unknown), record.get("tau", unknown)
        wrench = np.full((q.shape[0], 3), np.nan)
        joints: dict[str, np.ndarray] = {
            "joint_angles_deg": np.where(prismatic, np.nan, np.degrees(q)),
            "joint_velocities_deg_s": np.where(prismatic, np.nan, np.degrees(qd)),
        }
        if np.any(prismatic):
            joints["joint_displacements_m"] = np.where(prismatic, q, np.nan)
            joints["joint_velocities_m_s"] = np.where(prismatic, qd, np.nan)
        dynamics: dict[str, np.ndarray] = {
            "joint_accelerations_deg_s2": np.where(prismatic, np.nan, np.degrees(qdd)),
            "joint_torques_n_m": np.where(prismatic, np.nan, tau),
            "mount_force_n": record.get("mount_force", wrench),
            "mount_torque_n_m": record.get("mount_torque", wrench),
        }
        if np.any(prismatic):
            dynamics["joint_accelerations_m_s2"] = np.where(prismatic, qdd, np.nan)
            dynamics["joint_forces_n"] = np.where(prismatic, tau, np.nan)
        return {
            "t_s": record["t"],
            **joints,
            "base_position_m": record["base_position"],
            "base_attitude_quaternion": record["base_attitude"],
            "ee_position_m": record["ee_position"],
            "ee_position_desired_m": record["ee_position_desired"],
            "ee_attitude_quaternion": record["ee_attitude"],
            "ee_attitude_desired_quaternion": record["ee_attitude_desired"],
            "singular_values": record["singular_values"],
            "det_gjm": record["det_J_g"],
            "damping": record["damping"],
            "position_error_m": record["position_error"],
            "attitude_error_rad": record["attitude_error"],
            **{name: dynamics[name] for name in DYNAMICS_ORDER if name in dynamics},
            **({"clearance_m": record["clearance"]} if "clearance" in record else {}),
        }


#: The order of the dynamics arrays in a trajectory (as the schema declares them).
DYNAMICS_ORDER = (
    "joint_accelerations_deg_s2",
    "joint_accelerations_m_s2",
    "joint_torques_n_m",
    "joint_forces_n",
    "mount_force_n",
    "mount_torque_n_m",
)


class ReplayOut(Output):
    """The independent replay: the plan's joint rates re-integrated through the momentum equations
    (DOP853), compared with the path and with the plan; null where not finite or not replayed."""

    success: bool = Field(description="the replay stays on the path and conserves momentum within the tolerances")
    message: str = Field(description="the verdict, for a person (or why the plan was not replayed)")
    path_position_error_max_m: float | None = Field(description="largest position error of the replay against the path, m")
    path_position_error_final_m: float | None = Field(description="position error of the replay at the end, m")
    path_attitude_error_max_rad: float | None = Field(description="largest attitude error of the replay against the path, rad")
    path_attitude_error_final_rad: float | None = Field(description="attitude error of the replay at the end, rad")
    plan_gap_position_max_m: float | None = Field(description="largest end-effector position gap, replay versus plan, m")
    plan_gap_attitude_max_rad: float | None = Field(description="largest end-effector attitude gap, replay versus plan, rad")
    base_attitude_gap_max_rad: float | None = Field(description="largest base attitude gap, replay versus plan, rad")
    linear_momentum_residual_max_n_s: float | None = Field(description="largest linear momentum of the system, N s (ideally 0)")
    angular_momentum_residual_max_n_m_s: float | None = Field(
        description="largest angular momentum of the system, N m s (ideally 0)"
    )
    com_drift_max_m: float | None = Field(description="largest drift of the system's centre of mass, m (ideally 0)")
    executed_path_position_error_max_m: float | None = Field(
        default=None,
        description="the executed trajectory (the clamped cubic spline through the plan's samples, whose torques the plan "
        "reports) replayed the same way: its largest position error against the path, m",
    )
    executed_path_attitude_error_max_rad: float | None = Field(
        default=None, description="the executed trajectory's largest attitude error against the path, rad"
    )
    executed_plan_gap_position_max_m: float | None = Field(
        default=None,
        description="largest end-effector position gap, executed trajectory versus plan, m: how much executing the plan "
        "smoothly changes its tracking",
    )
    executed_plan_gap_attitude_max_rad: float | None = Field(
        default=None, description="largest end-effector attitude gap, executed trajectory versus plan, rad"
    )

    @classmethod
    def from_engine(cls, r: ReplayResult, executed: ReplayResult | None = None) -> ReplayOut:
        values = {
            "path_position_error_max_m": r.path_position_error_max,
            "path_position_error_final_m": r.path_position_error_final,
            "path_attitude_error_max_rad": r.path_attitude_error_max,
            "path_attitude_error_final_rad": r.path_attitude_error_final,
            "plan_gap_position_max_m": r.plan_gap_position_max,
            "plan_gap_attitude_max_rad": r.plan_gap_attitude_max,
            "base_attitude_gap_max_rad": r.base_attitude_gap_max,
            "linear_momentum_residual_max_n_s": r.linear_momentum_residual_max,
            "angular_momentum_residual_max_n_m_s": r.angular_momentum_residual_max,
            "com_drift_max_m": r.com_drift_max,
        }
        if executed is not None:
            values |= {
                "executed_path_position_error_max_m": executed.path_position_error_max,
                "executed_path_attitude_error_max_rad": executed.path_attitude_error_max,
                "executed_plan_gap_position_max_m": executed.plan_gap_position_max,
                "executed_plan_gap_attitude_max_rad": executed.plan_gap_attitude_max,
            }
        return cls(
            success=r.success,
            message=r.message,
            **{k: float(v) if math.isfinite(v) else None for k, v in values.items()},
        )

    @classmethod
    def skipped(cls, reason: str) -> ReplayOut:
        """The replay section of a plan that was not replayed, and why."""
        return cls(success=False, message=reason, **dict.fromkeys(cls.model_fields.keys() - {"success", "message"}))


class PlanSummary(Output):
    id: str = Field(description="the plan's id (32 hex digits)")
    robot_id: str | None = Field(description="the stored robot planned for; null for an inline robot")
    request: PlanRequest | None = Field(
        description="what the plan was asked: its request as stored, every default filled in (the task with its path, "
        "the method, the options); post it to `/v1/plans` to plan it again, or give the plan's id as `from_plan_id` "
        "with changes. Null for a plan stored by an earlier version whose request this version does not read"
    )
    method: MethodOut = Field(description="the robust inverse used, every parameter filled in")
    success: bool = Field(description="the plan is finite, within the joint speed limit, on the path and at the target")
    message: str = Field(description="the verdict, for a person (where and why a plan failed)")
    metrics: PlanMetrics = Field(description="what the plan achieved")
    robustness: RobustnessOut | None = Field(
        default=None, description="the plan on the sampled robots of the request's `uncertainty`; null without one"
    )
    elapsed_s: float = Field(description="time spent planning (and replaying), s")
    created_at: datetime = Field(description="when it was stored (UTC)")


PLAN_SECTIONS = ("trajectory", "replay")


class PlanOut(PlanSummary):
    """A plan: the summary, and the sections asked for with ``fields`` (all by default)."""

    # the sections are left out unless asked for: not required
    model_config = ConfigDict(json_schema_extra=_not_required("trajectory", "replay"))

    trajectory: Trajectory | None = Field(
        default=None, description="every sample of the plan (left out when `fields` does not name it)"
    )
    replay: ReplayOut | None = Field(default=None, description="the independent replay's checks; null if not replayed")


class PlanList(Output):
    items: list[PlanSummary] = Field(description="this page of plans (without trajectories), newest first")
    total: int = Field(description="number of plans stored")


# --- shortest feasible duration -----------------------------------------------------------


class DurationSearchSettings(Input):
    relative_tolerance: float = Field(
        default=DEFAULT_RELATIVE_TOLERANCE,
        gt=0,
        le=0.01,
        description="the search stops when the shortest feasible duration found is within this fraction "
        "(dimensionless) of the longest infeasible one below it (the boundary lies between them)",
    )
    candidates: int = Field(default=4, ge=1, le=16, description="durations planned per bisection round (in parallel)")
    max_duration_s: float | None = Field(
        default=None, gt=0, le=MAX_DURATION_S, description="longest duration tried, s (default: the task limits)"
    )


class ShortestDurationRequest(PlanRequest):
    """A plan request whose task's duration is searched: the task's `duration_s` (or its path's
    own timing) is only the starting point."""

    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "task": PAPER_TASK_EXAMPLE,
                    "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
                    "replay": False,
                    "search": {"relative_tolerance": 0.002, "candidates": 4},
                }
            ]
        },
    )

    search: DurationSearchSettings = Field(default_factory=DurationSearchSettings, description="how the duration is searched")


class DurationSearchOut(Output):
    success: bool = Field(description="a feasible duration was found (false: none up to the longest duration tried)")
    message: str = Field(description="the search's verdict, for a person")
    duration_s: float = Field(description="the shortest feasible duration found, the plan's (the longest tried if none)")
    infeasible_duration_s: float | None = Field(
        description="the longest infeasible duration found below it, s (null if even one step was feasible)"
    )
    relative_gap: float | None = Field(
        description="duration_s / infeasible_duration_s - 1 (dimensionless): where the boundary may lie"
    )
    joint_speed_margin_deg_s: float | None = Field(description="joint speed limit minus the plan's peak joint speed, deg/s")
    limiting: str = Field(description="what fails at infeasible_duration_s (the plan verdict there)")
    evaluations: int = Field(description="metrics-only plans run by the search")
    rounds: int = Field(description="bisection rounds run")

    @classmethod
    def from_engine(cls, found: DurationSearch) -> DurationSearchOut:
        def number(value: float) -> float | None:
            return value if math.isfinite(value) else None

        return cls(
            success=found.success,
            message=found.message,
            duration_s=found.duration,
            infeasible_duration_s=number(found.infeasible_duration),
            relative_gap=number(found.relative_gap),
            joint_speed_margin_deg_s=number(math.degrees(found.speed_margin)),
            limiting=found.limiting,
            evaluations=found.evaluations,
            rounds=found.rounds,
        )


class ShortestDurationOut(Output):
    search: DurationSearchOut = Field(description="the search: the duration found and how close it is to the boundary")
    plan: PlanOut = Field(description="the stored plan at duration_s (its request carries that duration)")
