"""Request and response bodies (pydantic). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``.

Joint positions come in two index-aligned lists, one per unit: ``..._deg`` holds the revolute
joints (deg) and ``..._m`` the prismatic ones (m), each with null at the joints of the other
type (a list may be left out when the robot has no joint of its unit). So an all-revolute robot
keeps its plain ``q0_deg`` list."""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from typing import Annotated, Any, Literal, get_args

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    GetJsonSchemaHandler,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema
from typing_extensions import TypeAliasType

from engine.inverses import METHODS, ParamSpec
from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, check_weights
from engine.model import JOINT_TYPES
from engine.paths import ARC_ATTITUDES, MAX_PASSES, MAX_WAYPOINTS, PATH_TYPES, PROFILES
from engine.redundancy import MAX_CENTERING_GAIN, SECONDARY_OBJECTIVES
from engine.shortest import DEFAULT_RELATIVE_TOLERANCE
from engine.spatial import matrix_to_quaternion, rpy_spacedyn_to_matrix
from engine.trajectory import MAX_DURATION_S, MIN_DT_S, PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_RPY, TRACKS
from engine.tuning import MAX_BITS_PER_GENE, MAX_GENERATIONS, MAX_POPULATION, TASK_AGGREGATIONS
from engine.urdf import MAX_URDF_BYTES

# Every number in a request is bounded (an overflow inside the engine is ruled out by the schema).
MAX_LENGTH_M = 1e3
MAX_ANGLE_DEG = 36_000.0  # a hundred turns
MAX_INERTIA = 1e12  # kg m^2
MAX_MASS_KG = 1e9
MAX_MAGNITUDE = 1e6  # method parameters, gains, weights, quaternion components
Length = Annotated[float, Field(ge=-MAX_LENGTH_M, le=MAX_LENGTH_M)]
AngleDeg = Annotated[float, Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)]
Magnitude = Annotated[float, Field(ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)]
Mass = Annotated[float, Field(gt=0, le=MAX_MASS_KG, description="mass, kg")]
Vec3 = Annotated[list[Length], Field(min_length=3, max_length=3)]
Quaternion = Annotated[
    list[Magnitude],
    Field(min_length=4, max_length=4, description="unit quaternion [w, x, y, z] (normalised; must not be zero)"),
]
InertiaRow = Annotated[list[Annotated[float, Field(ge=-MAX_INERTIA, le=MAX_INERTIA)]], Field(min_length=3, max_length=3)]
Inertia = Annotated[
    list[InertiaRow],
    Field(
        min_length=3,
        max_length=3,
        description="kg m^2; symmetric positive definite, each principal moment at most the sum of the others",
    ),
]
RotationRow = Annotated[list[Annotated[float, Field(ge=-1.000001, le=1.000001)]], Field(min_length=3, max_length=3)]
Rotation = Annotated[list[RotationRow], Field(min_length=3, max_length=3, description="a rotation matrix (orthonormal, det +1)")]
JointValue = Annotated[float, Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)]
#: Joint positions of one unit, index-aligned with the robot's joints (null: a joint of the other unit).
JointValues = Annotated[list[JointValue | None], Field(min_length=1, max_length=12)]
LimitValue = Annotated[float, Field(ge=-MAX_MAGNITUDE, le=MAX_MAGNITUDE)]

#: The unit of the GJM's determinant (and of the product of its singular values): three linear
#: rows in m (m/s per rad/s) and three angular rows without unit.
DET_UNITS = "m^3 (three rows in m per rad, three without unit)"

# Closed vocabularies, each a named schema (an enum class in generated clients), as the engine
# defines them (checked here so the two cannot drift). Literals, not enums: strict validation of
# a stored request (a dict) accepts the plain strings.
MethodName = TypeAliasType("MethodName", Literal["inverse", "dls", "adaptive", "wdls", "sdls", "svf"])
TunableMethodName = TypeAliasType("TunableMethodName", Literal["dls", "adaptive", "wdls", "sdls", "svf"])
AggregationName = TypeAliasType("AggregationName", Literal["max", "rms", "final"])
AttitudeTermName = TypeAliasType("AttitudeTermName", Literal["angle", "eq18"])
TaskAggregationName = TypeAliasType("TaskAggregationName", Literal["mean", "max"])
TimeProfile = TypeAliasType("TimeProfile", Literal["trapezoidal", "quintic"])
ArcAttitude = TypeAliasType("ArcAttitude", Literal["tangent", "fixed"])
JobStatus = TypeAliasType("JobStatus", Literal["queued", "running", "succeeded", "failed", "cancelled"])
JointType = TypeAliasType("JointType", Literal["revolute", "prismatic"])
JointUnit = TypeAliasType("JointUnit", Literal["deg", "m"])
TrackedQuantity = TypeAliasType("TrackedQuantity", Literal["pose", "position"])
SecondaryObjective = TypeAliasType("SecondaryObjective", Literal["min_base_rotation", "joint_centering"])
assert list(get_args(MethodName.__value__)) == list(METHODS)
assert list(get_args(TunableMethodName.__value__)) == [name for name, spec in METHODS.items() if spec.params]
assert set(get_args(AggregationName.__value__)) == set(AGGREGATIONS)
assert set(get_args(AttitudeTermName.__value__)) == set(ATTITUDE_TERMS)
assert set(get_args(TaskAggregationName.__value__)) == set(TASK_AGGREGATIONS)
assert set(get_args(TimeProfile.__value__)) == set(PROFILES)
assert set(get_args(ArcAttitude.__value__)) == set(ARC_ATTITUDES)
assert list(get_args(JointType.__value__)) == list(JOINT_TYPES)
assert set(get_args(TrackedQuantity.__value__)) == set(TRACKS)
assert set(get_args(SecondaryObjective.__value__)) == set(SECONDARY_OBJECTIVES)
AttitudeTerm = Annotated[
    AttitudeTermName,
    Field(
        description="attitude term of B: `eq18` (default) = the paper's eq. 18 as printed, sqrt(sum (dp_i dphi_i)^2) "
        "(m rad), which reproduces the paper's B values and its tuned-adaptive-versus-DLS margin; `angle` = the "
        "attitude error as a rotation angle (rad), frame independent, under which that margin shrinks to a few per cent"
    ),
]


AGGREGATION_DESCRIPTION = (
    "how the errors along the plan enter B: `max` (the largest), `rms` (root mean square over the samples) or `final` "
    "(at the end)"
)


def _weights(value: list[float]) -> list[float]:
    return list(check_weights(value))


Weights = Annotated[
    list[Annotated[float, Field(ge=0, le=MAX_MAGNITUDE)]],
    Field(min_length=2, max_length=2, description="(w1, w2) of B: finite, >= 0, not both zero"),
    AfterValidator(_weights),
]

PAPER_TARGET_QUATERNION = [round(float(x), 12) for x in matrix_to_quaternion(rpy_spacedyn_to_matrix(PAPER_TARGET_RPY))]

PAPER_TASK_EXAMPLE: dict[str, Any] = {
    "q0_deg": list(PAPER_Q0_DEG),
    "target_position_m": list(PAPER_TARGET_POSITION),
    "target_attitude_quaternion": PAPER_TARGET_QUATERNION,
    "duration_s": 15.0,
    "ramp_time_s": 1.5,
    "dt_s": 0.25,
    "profile": "trapezoidal",
    "joint_speed_limit_deg_s": 6.0,
}


def _no_nul(value: Any) -> Any:
    """Text must not contain NUL characters (PostgreSQL cannot store them; no field needs them)."""
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError("must not contain NUL characters (\\u0000)")
    elif isinstance(value, dict):
        for key, item in value.items():
            _no_nul(key)
            _no_nul(item)
    elif isinstance(value, list | tuple):
        for item in value:
            _no_nul(item)
    return value


class Input(BaseModel):
    """A request body, strictly typed: every number must be finite (NaN and infinities, which
    JSON parsers accept as ``NaN``/``Infinity`` literals or overflow to, are rejected with the
    field path), no text for a number and no number for a boolean, no unknown fields, no NUL
    characters in text."""

    model_config = ConfigDict(allow_inf_nan=False, strict=True, extra="forbid")

    @field_validator("*", mode="after")
    @classmethod
    def _text_without_nul(cls, value: Any) -> Any:
        return _no_nul(value)


class Output(BaseModel):
    """A response body: every field is always present (``required`` in the document's response
    schemas, so generated clients type them without ``Unset``); a field that may be null says so."""

    model_config = ConfigDict(json_schema_serialization_defaults_required=True)


def _not_required(*names: str) -> Callable[[dict[str, Any]], None]:
    """A ``json_schema_extra`` for an :class:`Output` whose fields ``names`` may be left out."""

    def drop(schema: dict[str, Any]) -> None:
        schema["required"] = [name for name in schema.get("required", []) if name not in names]

    return drop


# --- robots -------------------------------------------------------------------------------


class BaseParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the base link's name (default `base`)")
    mass: Mass
    inertia: Inertia = Field(description="kg m^2 about the base CoM, base frame")
    b: Vec3 = Field(description="m, base CoM to joint 1, base frame")


class JointLimits(Input):
    lower: LimitValue | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited below")
    upper: LimitValue | None = Field(default=None, description="rad (revolute) or m (prismatic); null: unlimited above")


class LinkParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the link's name (for reports only)")
    mass: Mass
    joint_type: JointType = Field(
        default="revolute", description="revolute: q in rad about joint_axis; prismatic: q in m along it"
    )
    joint_name: str | None = Field(default=None, max_length=200, description="the joint's name (default `joint<i>`)")
    joint_axis: Vec3 = Field(
        description="joint axis in the link frame, a direction (dimensionless; normalised, must not be zero)"
    )
    a: Vec3 = Field(description="m, joint i to link i CoM (at q = 0), link frame")
    b: Vec3 = Field(description="m, link i CoM to joint i+1 (or the end effector), link frame")
    inertia: Inertia = Field(description="kg m^2 about the link CoM, link frame")
    limits: JointLimits | None = Field(default=None, description="position limits (SI); null: unlimited")


class EndEffectorParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the end-effector frame's name")
    C_e: Rotation = Field(description="end-effector frame in the last link's frame (rotation matrix)")


class RobotParams(Input):
    """A robot parameter set in the schema of ``robot-table1.yaml`` (SI units)."""

    name: str = Field(min_length=1, max_length=200, description="the robot's name")
    base: BaseParams = Field(description="the free-floating base (carrier)")
    links: list[LinkParams] = Field(min_length=1, max_length=12, description="the links from the base out, one per joint")
    end_effector: EndEffectorParams | None = Field(
        default=None, description="the end-effector frame (default: the last link's frame)"
    )


class RobotUrdfIn(Input):
    """A robot from a URDF file, sent as text in the JSON body (``urdf``): the root link is the
    floating base, fixed joints are merged, the chain runs to ``end_effector_link``."""

    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={"examples": [{"urdf": "<robot name='my-arm'>...</robot>", "end_effector_link": "tool0"}]},
    )

    urdf: str = Field(min_length=1, max_length=MAX_URDF_BYTES, description="the URDF document (XML text, no DTD)")
    end_effector_link: str | None = Field(
        default=None, max_length=200, description="the end-effector link; default: the only leaf after the last moving joint"
    )
    tool_position_m: Vec3 | None = Field(default=None, description="tool offset: position in end_effector_link's frame, m")
    tool_attitude_quaternion: Quaternion | None = Field(
        default=None, description="tool offset: attitude in end_effector_link's frame [w, x, y, z] (default identity)"
    )
    name: str | None = Field(default=None, min_length=1, max_length=200, description="the robot's name (default: the URDF's)")


class JointOut(Output):
    """A joint of a stored robot, with the unit of its position in the API and its limits."""

    name: str = Field(description="the joint's name")
    type: JointType = Field(description="revolute or prismatic")
    unit: JointUnit = Field(description="the unit of its position in the API: `_deg` or `_m` lists")
    lower_deg: float | None = Field(default=None, description="revolute joints: lower position limit, deg (null: unlimited)")
    upper_deg: float | None = Field(default=None, description="revolute joints: upper position limit, deg (null: unlimited)")
    lower_m: float | None = Field(default=None, description="prismatic joints: lower position limit, m (null: unlimited)")
    upper_m: float | None = Field(default=None, description="prismatic joints: upper position limit, m (null: unlimited)")


class RobotOut(Output):
    id: str = Field(description="the robot's id (`table1` for the paper's robot)")
    name: str = Field(description="the robot's name")
    preset: bool = Field(description="a preset shipped with the service (cannot be deleted)")
    n_joints: int = Field(description="number of joints (and links)")
    parameters: RobotParams = Field(
        description="the parameter set, SI units, normalised (joint axes of unit length); derived from the URDF for URDF robots"
    )
    joints: list[JointOut] = Field(default_factory=list, description="the joints in chain order, with their units and limits")
    notes: list[str] = Field(default_factory=list, description="what the service assumed, e.g. joints without limits")
    created_at: datetime = Field(description="when it was stored (UTC)")


class RobotList(Output):
    items: list[RobotOut] = Field(description="this page of robots, oldest first")
    total: int = Field(description="number of robots stored")


class JacobianRequest(Input):
    """A state of the robot: its joint positions and the base pose."""

    joint_angles_deg: JointValues | None = Field(
        default=None, description="revolute joint angles, deg (null at prismatic joints)", examples=[list(PAPER_Q0_DEG)]
    )
    joint_displacements_m: JointValues | None = Field(
        default=None, description="prismatic joint positions, m (null at revolute joints)"
    )
    base_position_m: Vec3 | None = Field(default=None, description="base CoM in world, m (default origin)")
    base_attitude_quaternion: Quaternion | None = Field(default=None, description="base attitude [w, x, y, z] (default identity)")


class JacobianOut(Output):
    gjm: list[list[float]] = Field(description="6 x n generalized Jacobian: joint rates (rad/s) to [v (m/s); w (rad/s)]")
    singular_values: list[float] = Field(
        description="singular values of the GJM, descending (units of the GJM: m/rad for the linear rows, 1 for the angular)"
    )
    determinant: float | None = Field(description=f"det of the GJM, {DET_UNITS}; null unless it is square")
    manipulability: float = Field(
        description=f"the product of the singular values (sqrt(det(J J^T)) for 6 or more joints), {DET_UNITS}"
    )
    condition_number: float | None = Field(
        description="largest over smallest singular value (dimensionless); null if the GJM is singular"
    )
    ee_position_m: list[float] = Field(description="end-effector position, m (world)")
    ee_attitude_quaternion: list[float] = Field(description="end-effector attitude [w, x, y, z] (end effector -> world)")


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


# --- methods ------------------------------------------------------------------------------


def _omitted_when_none(value: Any) -> bool:
    return value is None


def _without_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


#: The units of the singular values of the GJM (which maps joint rates, rad/s, to [v (m/s); w
#: (rad/s)]: m/rad on the linear rows, 1 on the angular rows) and of the damping parameters.
SINGULAR_VALUE_UNITS = "in the units of the GJM's singular values"


def _param_specs(name: str) -> list[tuple[str, ParamSpec]]:
    """The methods that have a parameter ``name``, and its spec in each."""
    return [(method, p) for method, spec in METHODS.items() for p in spec.params if p.name == name]


def _method_param(name: str, meaning: str) -> Any:
    """A method parameter: optional, never null (left out when not given), its valid range the
    engine's (one range per name, whichever method uses it), its default per method."""
    specs = _param_specs(name)
    ranges = {(p.low, p.high, p.low_open) for _, p in specs}
    assert len(ranges) == 1, f"{name}: one valid range for every method that uses it"
    low, high, low_open = ranges.pop()
    defaults = ", ".join(f"{p.default:g} ({method})" for method, p in specs)
    return Field(
        default=None,
        alias=name,
        gt=low if low_open else None,
        ge=None if low_open else low,
        le=high,
        exclude_if=_omitted_when_none,
        json_schema_extra=_without_default,
        description=f"{meaning}; default {defaults}",
    )


def _param_bounds(name: str, unit: str) -> Any:
    """The GA's search interval of a method parameter: optional, never null."""
    defaults = ", ".join(f"[{p.tune_bounds[0]:g}, {p.tune_bounds[1]:g}] ({method})" for method, p in _param_specs(name))
    return Field(
        default=None,
        alias=name,
        exclude_if=_omitted_when_none,
        json_schema_extra=_without_default,
        description=f"[lo, hi] of `{name}`, {unit}, lo < hi within its valid range; default {defaults}",
    )


#: Parameter sets by their API names. A name no method has is refused by the document
#: (``additionalProperties: false``) but let through validation here: the engine's check then
#: names the parameters of the method chosen (``valid: lambda_max, epsilon``), which a schema
#: error ("extra inputs are not permitted") could not.
PARAMETER_NAMES_CONFIG = ConfigDict(
    serialize_by_alias=True,
    validate_by_alias=True,
    validate_by_name=False,
    extra="allow",
    json_schema_extra={"additionalProperties": False},
)


class MethodParams(Input):
    """Parameters of the robust inverse; give only those of the method named (each method's
    own: `dls`: `lambda`; `adaptive` and `wdls`: `lambda_max`, `epsilon`; `sdls`: `gamma_max`;
    `svf`: `sigma0`, `nu`; `inverse`: none). Missing ones take the method's defaults; a parameter
    of another method is a 422 naming it. Damping and singular-value thresholds are in the units
    of the GJM's singular values (the GJM maps joint rates in rad/s to [v (m/s); w (rad/s)])."""

    model_config = PARAMETER_NAMES_CONFIG

    lambda_: float = _method_param("lambda", f"dls: the constant damping lambda, {SINGULAR_VALUE_UNITS}")
    lambda_max: float = _method_param(
        "lambda_max", f"adaptive, wdls: the largest damping lambda_max (at a zero singular value), {SINGULAR_VALUE_UNITS}"
    )
    epsilon: float = _method_param(
        "epsilon", f"adaptive, wdls: the singular value epsilon below which damping starts, {SINGULAR_VALUE_UNITS}"
    )
    gamma_max: float = _method_param("gamma_max", "sdls: the largest joint rate gamma_max, rad/s")
    sigma0: float = _method_param("sigma0", f"svf: the smallest filtered singular value sigma_0, {SINGULAR_VALUE_UNITS}")
    nu: float = _method_param("nu", "svf: the shape factor nu of the filter (dimensionless)")

    def given(self) -> dict[str, float]:
        """The parameters given, by their API names."""
        return self.model_dump(exclude_none=True)


Interval = Annotated[list[Magnitude], Field(min_length=2, max_length=2)]


class MethodBounds(Input):
    """Search intervals of the GA, per parameter of the tuned method (the names of
    `MethodParams`); missing parameters take the default bounds, a parameter of another method
    is a 422 naming it."""

    model_config = PARAMETER_NAMES_CONFIG

    lambda_: Interval = _param_bounds("lambda", SINGULAR_VALUE_UNITS)
    lambda_max: Interval = _param_bounds("lambda_max", SINGULAR_VALUE_UNITS)
    epsilon: Interval = _param_bounds("epsilon", SINGULAR_VALUE_UNITS)
    gamma_max: Interval = _param_bounds("gamma_max", "rad/s")
    sigma0: Interval = _param_bounds("sigma0", SINGULAR_VALUE_UNITS)
    nu: Interval = _param_bounds("nu", "dimensionless")

    def given(self) -> dict[str, list[float]]:
        """The intervals given, by their API names."""
        return self.model_dump(exclude_none=True)


_PARAM_NAMES = {p.name for spec in METHODS.values() for p in spec.params}
for _model in (MethodParams, MethodBounds):
    assert {f.alias or name for name, f in _model.model_fields.items()} == _PARAM_NAMES, _model


class MethodIn(Input):
    """A robust inverse of the GJM and its parameters."""

    name: MethodName = Field(
        default="adaptive",
        description="`inverse` (plain, paper eq. 3), `dls` (constant damping, eq. 6), `adaptive` (the paper's "
        "per-singular-value damping, eq. 16), `wdls` (damping from the smallest singular value), `sdls` (selectively "
        "damped, Buss and Kim 2005), `svf` (singular value filtering, Colome and Torras 2015)",
    )
    params: MethodParams = Field(
        default_factory=MethodParams, description="the method's parameters; missing ones take the method's defaults"
    )


class SecondaryOut(Output):
    """The null-space objective a plan used, its gain filled in."""

    objective: SecondaryObjective = Field(description="the objective (see `SecondaryIn`)")
    gain: float = Field(description="min_base_rotation: in [0, 1], dimensionless; joint_centering: 1/s")


class MethodOut(Output):
    """The robust inverse a plan used, with every parameter of the method (defaults filled in),
    and the null-space objective if the plan had one."""

    model_config = ConfigDict(json_schema_extra=_not_required("secondary"))

    name: MethodName = Field(description="the method")
    params: MethodParams = Field(description="the method's parameters, every one of them")
    secondary: SecondaryOut | None = Field(
        default=None, exclude_if=_omitted_when_none, description="the null-space objective (left out when none)"
    )


class SecondaryIn(Input):
    """A secondary objective in the null space of a redundant arm (more joints than the task
    tracks: 7+ for a pose, 4+ for a position)."""

    objective: SecondaryObjective = Field(
        description="`min_base_rotation`: keep the carrier's attitude still (reaction null space); "
        "`joint_centering`: pull the joints towards the middle of their limits"
    )
    gain: float | None = Field(
        default=None,
        ge=0,
        le=MAX_CENTERING_GAIN,
        description="min_base_rotation: in [0, 1], dimensionless (1 = the full minimiser, default 1); joint_centering: 1/s "
        "(default 0.5)",
    )


TaskPreset.model_rebuild()


# --- plans --------------------------------------------------------------------------------


#: Vendor key of the schemas whose ``robot_id`` and ``robot`` are exclusive (see OneRobot).
ROBOT_CHOICE = "x-exactly-one-of"


class OneRobot(Input):
    """A request naming its robot: ``robot_id`` (a stored robot) or ``robot`` (inline), exactly
    one of the two (``oneOf`` in the schema)."""

    @classmethod
    def __get_pydantic_json_schema__(cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler) -> JsonSchemaValue:
        # Marked here, split in the OpenAPI document (service.openapi.split_robot_choice) into a
        # oneOf of two objects: not json_schema_extra, which a subclass's model_config replaces.
        schema = handler.resolve_ref_schema(handler(core_schema))
        schema[ROBOT_CHOICE] = ["robot_id", "robot"]
        return schema

    @model_validator(mode="after")
    def _exactly_one(self) -> Any:
        if (getattr(self, "robot_id", None) is None) == (getattr(self, "robot", None) is None):
            raise ValueError("give exactly one of robot_id (a stored robot, e.g. 'table1') and robot (inline parameters)")
        return self

    def stored(self) -> dict[str, Any]:
        """The request as stored (JSON; the robot field not given is left out, as in the request)."""
        data = self.model_dump(mode="json")
        for name in ("robot_id", "robot"):
            if data.get(name) is None:
                data.pop(name, None)
        return data


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
    weights: Weights = [0.5, 0.5]
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


# --- tuning jobs --------------------------------------------------------------------------


class GASettings(Input):
    """The paper's binary-coded genetic algorithm (DEAP)."""

    population: int = Field(default=40, ge=2, le=MAX_POPULATION, description="individuals per generation")
    generations: int = Field(default=50, ge=1, le=MAX_GENERATIONS, description="generations after the initial population")
    crossover_probability: float = Field(default=0.8, ge=0, le=1, description="probability that a pair is crossed over")
    mutation_probability: float = Field(default=0.02, ge=0, le=1, description="per-bit flip probability")
    bits_per_gene: int = Field(
        default=16, ge=2, le=MAX_BITS_PER_GENE, description="bits coding each parameter over its search interval"
    )
    elitism: int = Field(default=1, ge=0, description="best individuals kept unchanged; < population")
    seed: int | None = Field(default=0, ge=0, le=2**63 - 1, description="null for a random seed")

    @field_validator("elitism")
    @classmethod
    def _elitism_below_population(cls, value: int, info: ValidationInfo) -> int:
        population = info.data.get("population")
        if population is not None and value >= population:
            raise ValueError(f"must be smaller than population ({population})")
        return value


class ObjectiveSettings(Input):
    """The objective B the GA minimises (paper eq. 18), per task, then over the tasks."""

    weights: Weights = [0.5, 0.5]
    aggregation: AggregationName = Field(default="max", description=AGGREGATION_DESCRIPTION)
    attitude_term: AttitudeTerm = "eq18"
    task_aggregation: TaskAggregationName = Field(
        default="mean", description="how the tasks' B combine: `mean` or `max` (the worst task)"
    )


class TuningJobRequest(OneRobot):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "tasks": [PAPER_TASK_EXAMPLE],
                    "method": "adaptive",
                    "bounds": {"lambda_max": [0.0001, 0.2], "epsilon": [0.0001, 1.0]},
                    "ga": {
                        "population": 40,
                        "generations": 50,
                        "crossover_probability": 0.8,
                        "mutation_probability": 0.02,
                        "bits_per_gene": 16,
                        "elitism": 1,
                        "seed": 1,
                    },
                    "objective": {"weights": [0.5, 0.5], "aggregation": "max", "attitude_term": "eq18"},
                    "compare_with_dls": True,
                }
            ]
        },
    )

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None, min_length=1, max_length=64, description="a stored robot; or give `robot` inline (one of the two)"
    )
    robot: RobotParams = Field(default=None, description="inline robot parameters (instead of robot_id)")  # type: ignore[assignment]
    tasks: list[TaskIn] = Field(min_length=1, max_length=20, description="the tasks B is evaluated on")
    method: TunableMethodName = Field(default="adaptive", description="the inverse to tune (a method with parameters)")
    bounds: MethodBounds | None = Field(
        default=None, description="search interval [lo, hi] per parameter; missing parameters take the default bounds"
    )
    ga: GASettings = Field(default_factory=GASettings, description="the genetic algorithm's settings")
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings, description="the objective B")
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    compare_with_dls: bool = Field(default=True, description="also tune constant-damping DLS with the same GA settings")


class HistoryRecord(Output):
    generation: int = Field(description="the generation (0: the initial population)")
    best: float | None = Field(description="best objective B so far (null while nothing is feasible)")
    mean: float | None = Field(description="mean B of this generation's feasible individuals (null if none)")
    feasible: int = Field(description="feasible individuals in this generation (within the joint speed limit)")


PhaseRole = TypeAliasType("PhaseRole", Literal["tuned", "dls_baseline"])
PhaseName = TypeAliasType("PhaseName", Literal["dls", "adaptive", "wdls", "sdls", "svf", "done"])
assert list(get_args(PhaseName.__value__)) == [*get_args(TunableMethodName.__value__), "done"]


class JobPhase(Output):
    """One GA run of a job: the tuned method, then (with ``compare_with_dls``) the DLS baseline."""

    name: TunableMethodName = Field(description="the method this GA tunes")
    role: PhaseRole = Field(description="`tuned` (the job's method) or `dls_baseline`")
    generations: int = Field(description="generations of this GA (after the initial population)")
    completed: int = Field(description="generations of this GA finished so far (0 to `generations`)")
    history: list[HistoryRecord] = Field(description="one record per finished generation, from the initial population (0)")


class JobProgress(Output):
    generation: int = Field(default=0, description="generations finished, summed over the phases")
    generations: int = Field(default=0, description="generations of the whole job, summed over the phases")
    evaluations: int = Field(default=0, description="plans run so far (repeated genomes are not planned again)")
    best_objective_b: float | None = Field(default=None, description="best B of the running phase so far")
    best_params: MethodParams | None = Field(default=None, description="parameters of that best B (null before the first)")
    phase: PhaseName | None = Field(
        default=None, description="the running phase's method, `done` once finished; null while queued"
    )
    phases: list[JobPhase] = Field(default_factory=list, description="each GA of the job with its history")


class JobLinks(Output):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this job")
    result: str = Field(description="its result (409 until it succeeded)")
    events: str = Field(description="its Server-Sent Events (status changes and generations, live)")
    convergence_figure: str = Field(description="its convergence figure (paper Fig. 7), SVG; `?format=png` for PNG")


class TuningJobOut(Output):
    id: str = Field(description="the job's id (32 hex digits)")
    status: JobStatus = Field(description="queued, then running, then succeeded, failed or cancelled")
    robot_id: str | None = Field(description="the stored robot tuned for; null for an inline robot")
    method: TunableMethodName = Field(description="the method being tuned")
    progress: JobProgress = Field(description="how far the GA is")
    attempts: int = Field(description="times a worker claimed the job")
    max_attempts: int = Field(description="claims before the job is failed for good")
    cancel_requested: bool = Field(description="a cancellation was asked for")
    error: str | None = Field(description="why the job failed; null otherwise")
    created_at: datetime = Field(description="when it was submitted (UTC)")
    started_at: datetime | None = Field(description="when a worker last claimed it (UTC); null while queued")
    finished_at: datetime | None = Field(description="when it ended (UTC); null until then")
    links: JobLinks = Field(description="where the job's result, events and figure are")


class TuningJobList(Output):
    items: list[TuningJobOut] = Field(description="this page of jobs, newest first")
    total: int = Field(description="number of jobs (with the status asked for)")


class DLSBaseline(Output):
    lambda_: float | None = Field(
        alias="lambda", serialization_alias="lambda", description=f"the tuned DLS damping, {SINGULAR_VALUE_UNITS}"
    )
    objective_b: float | None = Field(description="B of the tuned DLS")
    warnings: list[str] = Field(default_factory=list, description="e.g. the tuned lambda on a search bound")

    model_config = ConfigDict(populate_by_name=True)


class TuningJobResult(Output):
    best_params: MethodParams = Field(description="the tuned parameters (those of the method)")
    best_objective_b: float | None = Field(description="their B; null if no individual was feasible")
    best_metrics: list[PlanMetrics] = Field(description="metrics of the best parameters, one per task")
    history: list[HistoryRecord] = Field(description="one row per generation of the tuned method")
    evaluations: int = Field(description="plans evaluated")
    elapsed_s: float = Field(description="time the GA took, s")
    dls_baseline: DLSBaseline | None = Field(description="DLS tuned with the same GA settings; null without `compare_with_dls`")
    improvement_over_dls_percent: float | None = Field(
        description="how much lower B is than the tuned DLS's, percent; null without a baseline"
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="e.g. a tuned parameter on a search bound, where the optimum may lie beyond it: widen that bound",
    )


HealthStatus = TypeAliasType("HealthStatus", Literal["ok", "unavailable"])


class Health(BaseModel):
    """Liveness or readiness; the fields other than `status` are left out where they do not apply."""

    status: HealthStatus = Field(description="`ok`, or `unavailable` (readiness: see the other fields)")
    kernels: str | None = Field(default=None, description="the engine's compiled kernels: loading, ok or failed: ...")
    database: str | None = Field(default=None, description="the database: ok, or what is wrong with it")
    revision: str | None = Field(default=None, description="the database's Alembic revision")
    head: str | None = Field(default=None, description="the Alembic revision this version of the service needs")


# --- objective landscapes

#: Methods with (at least) two parameters to span a landscape.
LandscapeMethod = TypeAliasType("LandscapeMethod", Literal["adaptive", "wdls", "svf"])
assert list(get_args(LandscapeMethod.__value__)) == [name for name, spec in METHODS.items() if len(spec.params) >= 2]
ParamName = TypeAliasType("ParamName", Literal["lambda", "lambda_max", "epsilon", "gamma_max", "sigma0", "nu"])
assert set(get_args(ParamName.__value__)) == _PARAM_NAMES
AxisScale = TypeAliasType("AxisScale", Literal["linear", "log"])


class LandscapeAxis(Input):
    """One axis of the grid: a parameter of the method and its values."""

    name: ParamName = Field(description="a parameter of the method, e.g. `lambda_max` or `epsilon` (see `MethodParams`)")
    min: Magnitude = Field(description="first value, in the parameter's unit (see `MethodParams`); > 0 on a log axis")
    max: Magnitude = Field(description="last value, in the parameter's unit (> min)")
    steps: int = Field(default=32, ge=2, le=128, description="values from min to max inclusive")
    scale: AxisScale = Field(default="linear", description="spacing of the values: `linear` or `log` (even in the logarithm)")


class LandscapeRequest(OneRobot):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "tasks": [PAPER_TASK_EXAMPLE],
                    "method": "adaptive",
                    "x": {"name": "lambda_max", "min": 0.001, "max": 0.2, "steps": 64},
                    "y": {"name": "epsilon", "min": 0.001, "max": 1.0, "steps": 64},
                }
            ]
        },
    )

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None, min_length=1, max_length=64, description="a stored robot; or give `robot` inline (one of the two)"
    )
    robot: RobotParams = Field(default=None, description="inline robot parameters (instead of robot_id)")  # type: ignore[assignment]
    tasks: list[TaskIn] = Field(min_length=1, max_length=8, description="B is their mean (or max, see objective)")
    method: LandscapeMethod = Field(default="adaptive", description="a method with two parameters or more")
    x: LandscapeAxis = Field(description="the parameter along the grid's rows (first index)")
    y: LandscapeAxis = Field(description="the parameter along the grid's columns (second index)")
    fixed: MethodParams | None = Field(
        default=None, description="the method's other parameters (default: their defaults); not those of the axes"
    )
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings, description="the objective B")
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    tuning_job_id: str = Field(  # type: ignore[assignment]
        default=None,
        pattern=r"^[0-9a-f]{32}$",
        description="a succeeded tuning job of the same method: its GA optimum is marked on the heatmap and "
        "its tuned DLS objective drawn as a contour (where the method beats the tuned DLS)",
    )


class LandscapeAxisOut(Output):
    name: ParamName = Field(description="the parameter along this axis")
    values: list[float] = Field(description="the parameter's values along this axis, in its unit (see `MethodParams`)")
    scale: AxisScale = Field(description="spacing of the values")


class LandscapeMarks(Output):
    tuning_job_id: str = Field(description="the tuning job marked on the heatmap")
    ga_optimum: MethodParams = Field(description="the job's tuned parameters")
    ga_objective_b: float | None = Field(description="the job's tuned B")
    dls_objective_b: float | None = Field(description="B of the job's tuned DLS baseline (null without one)")


class LandscapeLinks(Output):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this landscape")
    heatmap: str = Field(description="its heatmap figure, SVG; `?format=png` for PNG")


class LandscapeOut(Output):
    id: str = Field(description="the landscape's id (32 hex digits)")
    robot_id: str | None = Field(description="the stored robot; null for an inline robot")
    method: LandscapeMethod = Field(description="the method whose parameters span the grid")
    x: LandscapeAxisOut = Field(description="the grid's rows (first index)")
    y: LandscapeAxisOut = Field(description="the grid's columns (second index)")
    fixed: MethodParams = Field(description="the method's other parameters")
    objective_b: list[list[float | None]] = Field(description="B per cell [x index][y index]; null where infeasible")
    feasible: list[list[bool]] = Field(description="every task's plan finite and within the joint speed limit")
    max_joint_speed_deg_s: list[list[float | None]] = Field(
        description="the largest joint speed over the tasks, deg/s (null where a plan diverged)"
    )
    best_params: MethodParams = Field(description="the cell with the smallest B (empty if none is feasible)")
    best_objective_b: float | None = Field(description="B of that cell; null if none is feasible")
    feasible_fraction: float = Field(description="share of feasible cells, 0 to 1")
    marks: LandscapeMarks | None = Field(description="the tuning job named in the request; null if none")
    evaluations: int = Field(description="plans run: cells x tasks")
    elapsed_s: float = Field(description="s, computing the grid")
    created_at: datetime = Field(description="when it was stored (UTC)")
    links: LandscapeLinks = Field(description="where its heatmap is")
