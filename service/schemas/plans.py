"""Plans: the request, its metrics, trajectory and replay, and the shortest feasible duration."""

from __future__ import annotations

from datetime import datetime

from pydantic import (
    ConfigDict,
    Field,
)

from engine.shortest import DEFAULT_RELATIVE_TOLERANCE
from engine.trajectory import MAX_DURATION_S
from service.schemas.common import (
    AGGREGATION_DESCRIPTION,
    DET_UNITS,
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    SINGULAR_VALUE_UNITS,
    AggregationName,
    AttitudeTerm,
    AttitudeTermName,
    Input,
    OneRobot,
    Output,
    TrackedQuantity,
    Weights,
    _not_required,
)
from service.schemas.methods import MethodIn, MethodOut, SecondaryIn
from service.schemas.robots import RobotParams
from service.schemas.tasks import TaskIn


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

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None, min_length=1, max_length=64, description="a stored robot; or give `robot` inline (one of the two)"
    )
    robot: RobotParams = Field(default=None, description="inline robot parameters (instead of robot_id)")  # type: ignore[assignment]
    task: TaskIn = Field(description="the Cartesian task")
    method: MethodIn = Field(default_factory=MethodIn, description="the robust inverse (default: adaptive damping)")
    feedback_gain: float = Field(
        default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback added to the path twist"
    )
    aggregation: AggregationName = Field(default="max", description=AGGREGATION_DESCRIPTION)
    weights: Weights = [0.5, 0.5]  # noqa: RUF012 (a pydantic field: copied per instance)
    attitude_term: AttitudeTerm = "eq18"
    replay: bool = Field(default=True, description="re-integrate the plan with solve_ivp and report the gaps")
    secondary: SecondaryIn | None = Field(default=None, description="a null-space objective for a redundant arm")


#: Null in a number of a response: not finite (the plan diverged) or not applicable.
NULL_NOT_FINITE = "null if not finite"


class PlanMetrics(Output):
    """What a plan achieved: errors along the path (world frame, against the desired pose of
    each sample), joint speeds and the closest approach to a singularity."""

    objective_b: float | None = Field(
        description="objective B = w1 * position term (m) + w2 * attitude term (rad, or m rad with `eq18`), with the "
        "plan's aggregation; null when the joint speed limit is broken"
    )
    position_error_max_m: float | None = Field(description=f"largest end-effector position error, m; {NULL_NOT_FINITE}")
    position_error_rms_m: float | None = Field(description=f"root mean square position error, m; {NULL_NOT_FINITE}")
    position_error_final_m: float | None = Field(description=f"position error at the end, m; {NULL_NOT_FINITE}")
    attitude_error_max_rad: float | None = Field(description=f"largest attitude error (rotation angle), rad; {NULL_NOT_FINITE}")
    attitude_error_rms_rad: float | None = Field(description=f"root mean square attitude error, rad; {NULL_NOT_FINITE}")
    attitude_error_final_rad: float | None = Field(description=f"attitude error at the end, rad; {NULL_NOT_FINITE}")
    coupled_error_max_m_rad: float | None = Field(
        default=None, description="eq. 18 as printed, sqrt(sum (dp_i dphi_i)^2), largest, m rad; null if not finite"
    )
    coupled_error_rms_m_rad: float | None = Field(default=None, description="eq. 18 as printed, root mean square, m rad")
    coupled_error_final_m_rad: float | None = Field(default=None, description="eq. 18 as printed, at the end, m rad")
    attitude_term: AttitudeTermName = Field(
        default="angle", description="the attitude term B was formed with (plans stored before it was recorded: `angle`)"
    )
    max_joint_speed_deg_s: float | None = Field(description=f"largest speed of any revolute joint, deg/s; {NULL_NOT_FINITE}")
    joint_speed_limit_deg_s: float | None = Field(default=None, description="the task's revolute joint speed limit, deg/s")
    joint_speed_limit_respected: bool = Field(description="every joint within its speed limit at every sample")
    min_singular_value: float | None = Field(
        description=f"smallest singular value of the GJM along the plan, {SINGULAR_VALUE_UNITS}; {NULL_NOT_FINITE}"
    )
    time_of_min_singular_value_s: float | None = Field(description="when the smallest singular value occurred, s")
    min_abs_det_gjm: float | None = Field(
        description=f"smallest |det| of the tracked rows of the GJM along the plan, {DET_UNITS} for a pose task; null "
        "unless they are square, or if not finite"
    )
    time_of_min_abs_det_gjm_s: float | None = Field(description="when the smallest |det| occurred, s")
    tracks: TrackedQuantity = Field(default="pose", description="what the plan followed: the whole `pose` or the `position`")
    max_linear_joint_speed_m_s: float | None = Field(
        default=None, description=f"largest speed of any prismatic joint, m/s (0 without any); {NULL_NOT_FINITE}"
    )
    joint_speed_limit_m_s: float | None = Field(
        default=None, description="the task's prismatic joint speed limit, m/s; null: none"
    )
    position_limits_respected: bool | None = Field(
        default=None,
        description="every joint within its position limits at every sample (null: a plan stored before limits were checked)",
    )
    position_limit_joint: int | None = Field(
        default=None, description="the first joint (1-based index) found outside its limits; null if none"
    )
    time_position_limit_left_s: float | None = Field(default=None, description="when that joint left its limits, s; null if none")
    base_attitude_change_max_rad: float | None = Field(
        default=None, description=f"the carrier's largest rotation from its start, rad; {NULL_NOT_FINITE}"
    )
    base_attitude_change_final_rad: float | None = Field(
        default=None, description=f"the carrier's rotation from its start at the end, rad; {NULL_NOT_FINITE}"
    )


#: Trajectory arrays are time-major: one row per sample of `t_s`; null where a value is not finite.
PER_SAMPLE = "one row per sample of `t_s`"


class Trajectory(Output):
    """Every sample of a plan, time-major (one row per sample of `t_s`); null where a value is not
    finite (a diverged plan). Joint columns follow the robot's joints: revolute joints in the
    `_deg` arrays, prismatic ones in the `_m` arrays (null in the other's columns)."""

    model_config = ConfigDict(json_schema_extra=_not_required("joint_displacements_m", "joint_velocities_m_s"))

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


class PlanSummary(Output):
    id: str = Field(description="the plan's id (32 hex digits)")
    robot_id: str | None = Field(description="the stored robot planned for; null for an inline robot")
    method: MethodOut = Field(description="the robust inverse used, every parameter filled in")
    success: bool = Field(description="the plan is finite, within the joint speed limit, on the path and at the target")
    message: str = Field(description="the verdict, for a person (where and why a plan failed)")
    metrics: PlanMetrics = Field(description="what the plan achieved")
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


class ShortestDurationOut(Output):
    search: DurationSearchOut = Field(description="the search: the duration found and how close it is to the boundary")
    plan: PlanOut = Field(description="the stored plan at duration_s (its request carries that duration)")
