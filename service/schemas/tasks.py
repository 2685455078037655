"""Cartesian tasks and their paths, and task presets."""

from __future__ import annotations

from typing import Annotated, Literal, get_args

from pydantic import (
    AfterValidator,
    ConfigDict,
    Field,
)

from engine.paths import MAX_PASSES, MAX_WAYPOINTS, PATH_TYPES
from engine.trajectory import MAX_DURATION_S, MIN_DT_S
from service.schemas.common import (
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    ArcAttitude,
    Input,
    JointValues,
    Output,
    Quaternion,
    TimeProfile,
    TrackedQuantity,
    Vec3,
)
from service.schemas.methods import MethodIn

# --- tasks --------------------------------------------------------------------------------


UNIT_QUATERNION_TOLERANCE = 1e-6
#: Coordinates of path geometry (m): far beyond any robot's reach, small enough to stay finite.
MAX_COORDINATE_M = 1e4


def _unit_quaternion(value: list[float]) -> list[float]:
    norm = sum(x * x for x in value) ** 0.5
    if abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE:
        raise ValueError(
            f"must be a unit quaternion [w, x, y, z] (norm 1 within {UNIT_QUATERNION_TOLERANCE:g}), got norm {norm:.9g}"
        )
    return value


UnitQuaternion = Annotated[
    list[float],
    Field(min_length=4, max_length=4, description="unit quaternion [w, x, y, z] (norm 1 within 1e-6)"),
    AfterValidator(_unit_quaternion),
]
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
Point3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]


class PoseIn(Input):
    position_m: Point3 = Field(description="end-effector position, m (world)")
    attitude_quaternion: UnitQuaternion = Field(description="end-effector attitude [w, x, y, z] (end effector -> world)")


class MoveLimits(Input):
    """Limits that time rest-to-rest moves (quintic): each move takes the shortest duration
    within all four."""

    max_speed_m_s: float = Field(default=0.05, gt=0, le=100, description="maximum linear speed, m/s")
    max_angular_speed_deg_s: float = Field(default=5.0, gt=0, le=3600, description="maximum angular speed, deg/s")
    max_acceleration_m_s2: float = Field(default=0.02, gt=0, le=100, description="maximum linear acceleration, m/s^2")
    max_angular_acceleration_deg_s2: float = Field(
        default=2.0, gt=0, le=3600, description="maximum angular acceleration, deg/s^2"
    )


class LinePathIn(Input):
    """The paper's straight line from the start pose to the task's `target_position_m` and
    `target_attitude_quaternion`, the attitude rotating about one fixed axis; timed by the task's
    `duration_s` (default 15), `profile` and `ramp_time_s`."""

    type: Literal["line"] = Field(default="line", description="the path type")


class WaypointsPathIn(MoveLimits):
    """Poses visited in order from the start pose: each segment a straight line and an SO(3)
    geodesic on one quintic time law, rest to rest (the path passes through every pose with
    continuous velocity and acceleration). Timed by the limits, or by `segment_durations_s`;
    the task's `duration_s`, if given, rescales the whole path to it."""

    type: Literal["waypoints"] = Field(description="the path type")
    waypoints: list[PoseIn] = Field(min_length=1, max_length=MAX_WAYPOINTS, description="poses to visit, in order")
    segment_durations_s: list[Annotated[float, Field(gt=0, le=MAX_DURATION_S)]] | None = Field(
        default=None, description="s, one per waypoint (the segment that ends there); replaces the limits"
    )


class ArcPathIn(Input):
    """A circular arc from the start position: either `centre_m`, `axis` and `angle_deg` (the
    start turned about the line through the centre along the axis, right hand), or
    `via_position_m` and `end_position_m` (the circle through the start, via and end points).
    Timed like a line by the task's `duration_s` (default 15), `profile` and `ramp_time_s`."""

    type: Literal["arc"] = Field(description="the path type")
    centre_m: Point3 | None = Field(default=None, description="a point on the arc's axis, m")
    axis: Point3 | None = Field(default=None, description="direction of the arc's axis (normalised)")
    angle_deg: float | None = Field(default=None, ge=-360, le=360, description="turn about the axis, deg (right hand)")
    via_position_m: Point3 | None = Field(default=None, description="a point the arc passes through, m")
    end_position_m: Point3 | None = Field(default=None, description="where the arc ends, m")
    attitude: ArcAttitude = Field(
        default="tangent",
        description="`tangent`: the attitude turns with the arc (fixed relative to its tangent frame); `fixed`: held",
    )


class RasterPathIn(MoveLimits):
    """A boustrophedon scan of the rectangle `corner_m + x scan_edge_m + y step_edge_m` (x, y in
    [0, 1]) from the side of its normal `n = scan_edge x step_edge` (normalised): the end
    effector at `standoff_m` along n, the sensor axis pointing at the patch (along -n). Passes run
    along the scan edge every `line_spacing_m` along the step edge, alternating direction, joined
    outside the patch by turns of `turn_radius_m`; the whole scan at `scan_speed_m_s` with
    ramps of `scan_acceleration_m_s2` at its ends, after a quintic approach (the limits) from the
    start pose. The task's `duration_s`, if given, rescales the whole path to it."""

    type: Literal["raster"] = Field(description="the path type")
    corner_m: Point3 = Field(description="a corner of the patch, m")
    scan_edge_m: Point3 = Field(description="edge vector the passes run along, m")
    step_edge_m: Point3 = Field(description="edge vector the passes step along (perpendicular to the scan edge), m")
    line_spacing_m: float = Field(
        gt=0, le=MAX_COORDINATE_M, description="distance between passes, m (at most the step edge's length)"
    )
    standoff_m: float = Field(gt=0, le=MAX_COORDINATE_M, description="sensor distance from the patch along its normal, m")
    scan_speed_m_s: float = Field(gt=0, le=100, description="speed along the scan, m/s")
    scan_acceleration_m_s2: float = Field(
        default=0.01, gt=0, le=100, description="acceleration at the scan's start and end, m/s^2"
    )
    turn_radius_m: float | None = Field(
        default=None,
        gt=0,
        le=MAX_COORDINATE_M,
        description="radius of the turns between passes, m (default and at most half the spacing)",
    )
    sensor_axis: Point3 = Field(default=[0.0, 0.0, 1.0], description="the sensor's axis in the end-effector frame (normalised)")
    pass_index: int | None = Field(
        default=None,
        ge=0,
        lt=MAX_PASSES,
        description="scan only this pass (0-based) after the approach: one task per pass for tuning",
    )


PathIn = Annotated[LinePathIn | WaypointsPathIn | ArcPathIn | RasterPathIn, Field(discriminator="type")]
PathType = Literal["line", "waypoints", "arc", "raster"]
assert set(get_args(PathType)) == set(PATH_TYPES)


class TaskIn(Input):
    """A Cartesian task: the end effector follows `path` (by default the straight line to the
    target pose) from the forward kinematics of ``q0_deg`` with the base at rest at the origin.
    Errors in path fields are reported at ``task.path.<type>.<field>``."""

    model_config = ConfigDict(json_schema_extra={"examples": [PAPER_TASK_EXAMPLE]}, allow_inf_nan=False)

    q0_deg: JointValues | None = Field(
        default=None, description="initial joint angles of the revolute joints, deg (null at prismatic joints)"
    )
    q0_m: JointValues | None = Field(
        default=None, description="initial positions of the prismatic joints, m (null at revolute joints)"
    )
    tracks: TrackedQuantity = Field(
        default="pose",
        description="what the plan follows: the whole `pose` (needs 6 joints or more) or the `position` only (3 or more)",
    )
    target_position_m: Vec3 | None = Field(
        default=None, description="target end-effector position, m (line paths only, required)"
    )
    target_attitude_quaternion: Quaternion | None = Field(
        default=None,
        description="target end-effector attitude [w, x, y, z] (line paths only, normalised; required for pose tasks, "
        "position tasks keep the start one)",
    )
    duration_s: float | None = Field(
        default=None,
        gt=0,
        le=MAX_DURATION_S,
        description="s; line and arc: default 15; waypoints and raster: default the path's own timing, else rescaled to it",
    )
    ramp_time_s: float = Field(default=1.5, ge=0, le=300, description="s, trapezoidal profile only; at most duration_s / 2")
    dt_s: float = Field(default=0.25, ge=MIN_DT_S, le=1, description="planner step, s; duration_s / dt_s at most 20,000 steps")
    profile: TimeProfile = Field(default="trapezoidal", description="time law of line and arc paths")
    joint_speed_limit_deg_s: float = Field(
        default=6.0, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the revolute joints, deg/s"
    )
    joint_speed_limit_m_s: float | None = Field(
        default=None, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the prismatic joints, m/s (null: none)"
    )
    path: PathIn = Field(default_factory=LinePathIn, description="the path type and its parameters (default: line)")


class TaskPreset(Output):
    """A named task, in the shape of the request fields it fills (`robot_id`, `task`, `method` of
    a plan request)."""

    name: str = Field(description="the preset's name (its id)")
    description: str = Field(description="what the task is, for a person")
    robot_id: str = Field(description="the stored robot the task is meant for")
    task: TaskIn = Field(description="the task, ready to post")
    method: MethodIn | None = Field(
        default=None, description="the method and parameters the preset is meant to be planned with (null: any)"
    )


class TaskPresetList(Output):
    items: list[TaskPreset] = Field(description="every task preset")
    total: int = Field(description="number of task presets")
