"""Request and response bodies (pydantic). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``.

Joint positions come in two index-aligned lists, one per unit: ``..._deg`` holds the revolute
joints (deg) and ``..._m`` the prismatic ones (m), each with null at the joints of the other
type (a list may be left out when the robot has no joint of its unit). So an all-revolute robot
keeps its plain ``q0_deg`` list."""

from __future__ import annotations

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

from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, check_weights
from engine.paths import ARC_ATTITUDES, MAX_PASSES, MAX_WAYPOINTS, PATH_TYPES
from engine.redundancy import MAX_CENTERING_GAIN
from engine.shortest import DEFAULT_RELATIVE_TOLERANCE
from engine.spatial import matrix_to_quaternion, rpy_spacedyn_to_matrix
from engine.trajectory import MAX_DURATION_S, MIN_DT_S, PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_RPY
from engine.tuning import MAX_BITS_PER_GENE, MAX_GENERATIONS, MAX_POPULATION
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
Mass = Annotated[float, Field(gt=0, le=MAX_MASS_KG, description="kg")]
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

# The objective's options, as the engine defines them (checked below so the two cannot drift).
AggregationName = Literal["max", "rms", "final"]
AttitudeTermName = Literal["angle", "eq18"]
assert set(get_args(AggregationName)) == set(AGGREGATIONS) and set(get_args(AttitudeTermName)) == set(ATTITUDE_TERMS)
AttitudeTerm = Annotated[
    AttitudeTermName,
    Field(
        description="attitude term of B: `eq18` (default) = the paper's eq. 18 as printed, sqrt(sum (dp_i dphi_i)^2) "
        "(m rad), which reproduces the paper's B values and its tuned-adaptive-versus-DLS margin; `angle` = the "
        "attitude error as a rotation angle (rad), frame independent, under which that margin shrinks to a few per cent"
    ),
]


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
    name: str | None = Field(default=None, max_length=200)
    mass: Mass
    joint_type: Literal["revolute", "prismatic"] = Field(
        default="revolute", description="revolute: q in rad about joint_axis; prismatic: q in m along it"
    )
    joint_name: str | None = Field(default=None, max_length=200, description="the joint's name (default `joint<i>`)")
    joint_axis: Vec3 = Field(description="joint axis in the link frame (normalised; must not be zero)")
    a: Vec3 = Field(description="m, joint i to link i CoM (at q = 0), link frame")
    b: Vec3 = Field(description="m, link i CoM to joint i+1 (or the end effector), link frame")
    inertia: Inertia = Field(description="kg m^2 about the link CoM, link frame")
    limits: JointLimits | None = Field(default=None, description="position limits (SI); null: unlimited")


class EndEffectorParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the end-effector frame's name")
    C_e: Rotation = Field(description="end-effector frame in the last link's frame (rotation matrix)")


class RobotParams(Input):
    """A robot parameter set in the schema of ``robot-table1.yaml`` (SI units)."""

    name: str = Field(min_length=1, max_length=200)
    base: BaseParams
    links: list[LinkParams] = Field(min_length=1, max_length=12)
    end_effector: EndEffectorParams | None = None


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


class JointOut(BaseModel):
    name: str
    type: Literal["revolute", "prismatic"]
    unit: Literal["deg", "m"] = Field(description="the unit of its position in the API: `_deg` or `_m` lists")
    lower_deg: float | None = Field(default=None, description="revolute joints: lower position limit, deg (null: unlimited)")
    upper_deg: float | None = None
    lower_m: float | None = Field(default=None, description="prismatic joints: lower position limit, m (null: unlimited)")
    upper_m: float | None = None


class RobotOut(BaseModel):
    id: str
    name: str
    preset: bool
    n_joints: int
    parameters: dict[str, Any] = Field(description="the parameter set (SI units; derived from the URDF for URDF robots)")
    joints: list[JointOut] = Field(default_factory=list, description="the joints in chain order, with their units and limits")
    notes: list[str] = Field(default_factory=list, description="what the service assumed, e.g. joints without limits")
    created_at: datetime


class RobotList(BaseModel):
    items: list[RobotOut]
    total: int


class JacobianRequest(Input):
    joint_angles_deg: JointValues | None = Field(
        default=None, description="revolute joint angles, deg (null at prismatic joints)", examples=[list(PAPER_Q0_DEG)]
    )
    joint_displacements_m: JointValues | None = Field(
        default=None, description="prismatic joint positions, m (null at revolute joints)"
    )
    base_position_m: Vec3 | None = Field(default=None, description="base CoM in world, m (default origin)")
    base_attitude_quaternion: Quaternion | None = Field(default=None, description="base attitude [w, x, y, z] (default identity)")


class JacobianOut(BaseModel):
    gjm: list[list[float]] = Field(description="6 x n generalized Jacobian: joint rates (rad/s) to [v (m/s); w (rad/s)]")
    singular_values: list[float]
    determinant: float | None = Field(description="det of the GJM; null unless it is square")
    manipulability: float
    condition_number: float | None
    ee_position_m: list[float]
    ee_attitude_quaternion: list[float]


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

    type: Literal["line"] = "line"


class WaypointsPathIn(MoveLimits):
    """Poses visited in order from the start pose: each segment a straight line and an SO(3)
    geodesic on one quintic time law, rest to rest (the path passes through every pose with
    continuous velocity and acceleration). Timed by the limits, or by `segment_durations_s`;
    the task's `duration_s`, if given, rescales the whole path to it."""

    type: Literal["waypoints"]
    waypoints: list[PoseIn] = Field(min_length=1, max_length=MAX_WAYPOINTS, description="poses to visit, in order")
    segment_durations_s: list[Annotated[float, Field(gt=0, le=MAX_DURATION_S)]] | None = Field(
        default=None, description="s, one per waypoint (the segment that ends there); replaces the limits"
    )


class ArcPathIn(Input):
    """A circular arc from the start position: either `centre_m`, `axis` and `angle_deg` (the
    start turned about the line through the centre along the axis, right hand), or
    `via_position_m` and `end_position_m` (the circle through the start, via and end points).
    Timed like a line by the task's `duration_s` (default 15), `profile` and `ramp_time_s`."""

    type: Literal["arc"]
    centre_m: Point3 | None = Field(default=None, description="a point on the arc's axis, m")
    axis: Point3 | None = Field(default=None, description="direction of the arc's axis (normalised)")
    angle_deg: float | None = Field(default=None, ge=-360, le=360, description="turn about the axis, deg (right hand)")
    via_position_m: Point3 | None = Field(default=None, description="a point the arc passes through, m")
    end_position_m: Point3 | None = Field(default=None, description="where the arc ends, m")
    attitude: Literal["tangent", "fixed"] = Field(
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

    type: Literal["raster"]
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
assert set(get_args(PathType)) == set(PATH_TYPES) and ARC_ATTITUDES == ("tangent", "fixed")


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
    tracks: Literal["pose", "position"] = Field(
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
    profile: Literal["trapezoidal", "quintic"] = Field(default="trapezoidal", description="time law of line and arc paths")
    joint_speed_limit_deg_s: float = Field(
        default=6.0, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the revolute joints, deg/s"
    )
    joint_speed_limit_m_s: float | None = Field(
        default=None, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the prismatic joints, m/s (null: none)"
    )
    path: PathIn = Field(default_factory=LinePathIn, description="the path type and its parameters (default: line)")


class TaskPreset(BaseModel):
    name: str
    description: str
    robot_id: str
    task: TaskIn
    method: MethodIn | None = Field(default=None, description="the method and parameters the preset is meant to be planned with")


class TaskPresetList(BaseModel):
    items: list[TaskPreset]
    total: int


# --- plans --------------------------------------------------------------------------------


class MethodIn(Input):
    name: str = Field(default="adaptive", max_length=40, description="inverse: inverse, dls, adaptive, wdls, sdls, svf")
    params: dict[Annotated[str, Field(max_length=40)], Magnitude] = Field(
        default_factory=dict, max_length=4, description="method parameters; missing ones take defaults"
    )


class SecondaryIn(Input):
    """A secondary objective in the null space of a redundant arm (more joints than the task
    tracks: 7+ for a pose, 4+ for a position)."""

    objective: Literal["min_base_rotation", "joint_centering"] = Field(
        description="`min_base_rotation`: keep the carrier's attitude still (reaction null space); "
        "`joint_centering`: pull the joints towards the middle of their limits"
    )
    gain: float | None = Field(
        default=None,
        ge=0,
        le=MAX_CENTERING_GAIN,
        description="min_base_rotation: in [0, 1] (1 = the full minimiser, default 1); joint_centering: 1/s (default 0.5)",
    )


TaskPreset.model_rebuild()


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
    task: TaskIn
    method: MethodIn = Field(default_factory=MethodIn)
    feedback_gain: float = Field(
        default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback added to the path twist"
    )
    aggregation: AggregationName = "max"
    weights: Weights = [0.5, 0.5]
    attitude_term: AttitudeTerm = "eq18"
    replay: bool = Field(default=True, description="re-integrate the plan with solve_ivp and report the gaps")
    secondary: SecondaryIn | None = Field(default=None, description="a null-space objective for a redundant arm")


class PlanMetrics(BaseModel):
    objective_b: float | None = Field(description="objective B (m + rad weighted); null when the speed limit is broken")
    position_error_max_m: float | None
    position_error_rms_m: float | None
    position_error_final_m: float | None
    attitude_error_max_rad: float | None
    attitude_error_rms_rad: float | None
    attitude_error_final_rad: float | None
    coupled_error_max_m_rad: float | None = Field(default=None, description="eq. 18 as printed: sqrt(sum (dp_i dphi_i)^2)")
    coupled_error_rms_m_rad: float | None = None
    coupled_error_final_m_rad: float | None = None
    attitude_term: AttitudeTermName = Field(
        default="angle", description="the attitude term B was formed with (plans stored before it was recorded: `angle`)"
    )
    max_joint_speed_deg_s: float | None
    joint_speed_limit_deg_s: float | None = None
    joint_speed_limit_respected: bool
    min_singular_value: float | None
    time_of_min_singular_value_s: float | None
    min_abs_det_gjm: float | None = Field(description="of the tracked rows of the GJM when they are square; else null")
    time_of_min_abs_det_gjm_s: float | None
    tracks: Literal["pose", "position"] = "pose"
    max_linear_joint_speed_m_s: float | None = Field(default=None, description="prismatic joints (0 without any)")
    joint_speed_limit_m_s: float | None = None
    position_limits_respected: bool | None = None
    position_limit_joint: int | None = Field(default=None, description="the first joint (1-based) found outside its limits")
    time_position_limit_left_s: float | None = None
    base_attitude_change_max_rad: float | None = Field(default=None, description="the carrier's largest rotation from its start")
    base_attitude_change_final_rad: float | None = None


class Trajectory(BaseModel):
    t_s: list[float]
    joint_angles_deg: list[list[float | None]] = Field(description="revolute joints, deg (null in prismatic columns)")
    joint_velocities_deg_s: list[list[float | None]]
    joint_displacements_m: list[list[float | None]] | None = Field(
        default=None, description="prismatic joints, m (null in revolute columns); only for robots with prismatic joints"
    )
    joint_velocities_m_s: list[list[float | None]] | None = None
    base_position_m: list[list[float | None]]
    base_attitude_quaternion: list[list[float | None]]
    ee_position_m: list[list[float | None]]
    ee_position_desired_m: list[list[float | None]]
    ee_attitude_quaternion: list[list[float | None]]
    ee_attitude_desired_quaternion: list[list[float | None]]
    singular_values: list[list[float | None]]
    det_gjm: list[float | None]
    damping: list[list[float | None]]
    position_error_m: list[float | None]
    attitude_error_rad: list[float | None]


class ReplayOut(BaseModel):
    success: bool
    message: str
    path_position_error_max_m: float | None
    path_position_error_final_m: float | None
    path_attitude_error_max_rad: float | None
    path_attitude_error_final_rad: float | None
    plan_gap_position_max_m: float | None
    plan_gap_attitude_max_rad: float | None
    base_attitude_gap_max_rad: float | None
    linear_momentum_residual_max_n_s: float | None
    angular_momentum_residual_max_n_m_s: float | None
    com_drift_max_m: float | None


class PlanSummary(BaseModel):
    id: str
    robot_id: str | None
    method: dict[str, Any]
    success: bool
    message: str
    metrics: PlanMetrics
    elapsed_s: float
    created_at: datetime


PLAN_SECTIONS = ("trajectory", "replay")


class PlanOut(PlanSummary):
    """A plan: the summary, and the sections asked for with ``fields`` (all by default)."""

    trajectory: Trajectory | None = Field(
        default=None, description="every sample of the plan (left out when `fields` does not name it)"
    )
    replay: ReplayOut | None = Field(default=None, description="the independent replay's checks; null if not replayed")


class PlanList(BaseModel):
    items: list[PlanSummary]
    total: int


# --- shortest feasible duration -----------------------------------------------------------


class DurationSearchSettings(Input):
    relative_tolerance: float = Field(
        default=DEFAULT_RELATIVE_TOLERANCE,
        gt=0,
        le=0.01,
        description="the search stops when the shortest feasible duration found is within this fraction of the longest "
        "infeasible one below it (the boundary lies between them)",
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

    search: DurationSearchSettings = Field(default_factory=DurationSearchSettings)


class DurationSearchOut(BaseModel):
    success: bool = Field(description="a feasible duration was found (false: none up to the longest duration tried)")
    message: str
    duration_s: float = Field(description="the shortest feasible duration found, the plan's (the longest tried if none)")
    infeasible_duration_s: float | None = Field(
        description="the longest infeasible duration found below it, s (null if even one step was feasible)"
    )
    relative_gap: float | None = Field(description="duration_s / infeasible_duration_s - 1: where the boundary may lie")
    joint_speed_margin_deg_s: float | None = Field(description="joint speed limit minus the plan's peak joint speed, deg/s")
    limiting: str = Field(description="what fails at infeasible_duration_s (the plan verdict there)")
    evaluations: int = Field(description="metrics-only plans run by the search")
    rounds: int


class ShortestDurationOut(BaseModel):
    search: DurationSearchOut
    plan: PlanOut = Field(description="the stored plan at duration_s (its request carries that duration)")


# --- tuning jobs --------------------------------------------------------------------------

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class GASettings(Input):
    population: int = Field(default=40, ge=2, le=MAX_POPULATION)
    generations: int = Field(default=50, ge=1, le=MAX_GENERATIONS)
    crossover_probability: float = Field(default=0.8, ge=0, le=1)
    mutation_probability: float = Field(default=0.02, ge=0, le=1, description="per-bit flip probability")
    bits_per_gene: int = Field(default=16, ge=2, le=MAX_BITS_PER_GENE)
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
    weights: Weights = [0.5, 0.5]
    aggregation: AggregationName = "max"
    attitude_term: AttitudeTerm = "eq18"
    task_aggregation: Literal["mean", "max"] = "mean"


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
    tasks: list[TaskIn] = Field(min_length=1, max_length=20)
    method: str = Field(default="adaptive", max_length=40, description="the inverse to tune (a method with parameters)")
    bounds: dict[Annotated[str, Field(max_length=40)], Annotated[list[Magnitude], Field(min_length=2, max_length=2)]] | None = (
        Field(None, max_length=4, description="search interval [lo, hi] per parameter; missing parameters take default bounds")
    )
    ga: GASettings = Field(default_factory=GASettings)
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings)
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    compare_with_dls: bool = Field(default=True, description="also tune constant-damping DLS with the same GA settings")


class HistoryRecord(BaseModel):
    generation: int = Field(description="0 is the initial population")
    best: float | None = Field(description="best objective B so far (null while nothing is feasible)")
    mean: float | None = Field(description="mean B of this generation's feasible individuals (null if none)")
    feasible: int = Field(description="feasible individuals in this generation")


PhaseRole = Literal["tuned", "dls_baseline"]


class JobPhase(BaseModel):
    """One GA run of a job: the tuned method, then (with ``compare_with_dls``) the DLS baseline."""

    name: str = Field(description="the method this GA tunes")
    role: PhaseRole = Field(description="`tuned` (the job's method) or `dls_baseline`")
    generations: int = Field(description="generations of this GA (after the initial population)")
    completed: int = Field(description="generations of this GA finished so far (0 to `generations`)")
    history: list[HistoryRecord] = Field(description="one record per finished generation, from the initial population (0)")


class JobProgress(BaseModel):
    generation: int = Field(default=0, description="generations finished, summed over the phases")
    generations: int = Field(default=0, description="generations of the whole job, summed over the phases")
    evaluations: int = Field(default=0, description="plans run so far (repeated genomes are not planned again)")
    best_objective_b: float | None = Field(default=None, description="best B of the running phase so far")
    best_params: dict[str, float] | None = Field(default=None, description="parameters of that best B")
    phase: str | None = Field(default=None, description="the running phase's method, `done` once finished")
    phases: list[JobPhase] = Field(default_factory=list, description="each GA of the job with its history")


class JobLinks(BaseModel):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this job")
    result: str = Field(description="its result (409 until it succeeded)")
    events: str = Field(description="its Server-Sent Events (status changes and generations, live)")
    convergence_figure: str = Field(description="its convergence figure (paper Fig. 7), SVG; `?format=png` for PNG")


class TuningJobOut(BaseModel):
    id: str
    status: JobStatus
    robot_id: str | None
    method: str
    progress: JobProgress
    attempts: int
    max_attempts: int
    cancel_requested: bool
    error: str | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    links: JobLinks


class TuningJobList(BaseModel):
    items: list[TuningJobOut]
    total: int


class DLSBaseline(BaseModel):
    lambda_: float | None = Field(alias="lambda", serialization_alias="lambda")
    objective_b: float | None
    warnings: list[str] = Field(default_factory=list, description="e.g. the tuned lambda on a search bound")

    model_config = ConfigDict(populate_by_name=True)


class TuningJobResult(BaseModel):
    best_params: dict[str, float]
    best_objective_b: float | None
    best_metrics: list[PlanMetrics] = Field(description="metrics of the best parameters, one per task")
    history: list[HistoryRecord]
    evaluations: int
    elapsed_s: float
    dls_baseline: DLSBaseline | None
    improvement_over_dls_percent: float | None
    warnings: list[str] = Field(
        default_factory=list,
        description="e.g. a tuned parameter on a search bound, where the optimum may lie beyond it: widen that bound",
    )


class Health(BaseModel):
    status: str
    kernels: str | None = Field(default=None, description="the engine's compiled kernels: loading, ok or failed: ...")
    database: str | None = None
    revision: str | None = None
    head: str | None = None


# --- objective landscapes

#: Methods with (at least) two parameters to span a landscape.
LandscapeMethod = Literal["adaptive", "wdls", "svf"]


class LandscapeAxis(Input):
    name: str = Field(max_length=40, description="a parameter of the method, e.g. `lambda_max` or `epsilon`")
    min: Magnitude = Field(description="first value (in the parameter's unit; > 0 on a log axis)")
    max: Magnitude = Field(description="last value (> min)")
    steps: int = Field(default=32, ge=2, le=128, description="values from min to max inclusive")
    scale: Literal["linear", "log"] = Field(default="linear", description="spacing of the values")


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
    fixed: dict[Annotated[str, Field(max_length=40)], Magnitude] | None = Field(
        default=None, max_length=4, description="the method's other parameters (default: their defaults)"
    )
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings)
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    tuning_job_id: str = Field(  # type: ignore[assignment]
        default=None,
        pattern=r"^[0-9a-f]{32}$",
        description="a succeeded tuning job of the same method: its GA optimum is marked on the heatmap and "
        "its tuned DLS objective drawn as a contour (where the method beats the tuned DLS)",
    )


class LandscapeAxisOut(BaseModel):
    name: str
    values: list[float] = Field(description="the parameter's values along this axis")
    scale: Literal["linear", "log"]


class LandscapeMarks(BaseModel):
    tuning_job_id: str
    ga_optimum: dict[str, float] = Field(description="the job's tuned parameters")
    ga_objective_b: float | None = Field(description="the job's tuned B")
    dls_objective_b: float | None = Field(description="B of the job's tuned DLS baseline (null without one)")


class LandscapeLinks(BaseModel):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this landscape")
    heatmap: str = Field(description="its heatmap figure, SVG; `?format=png` for PNG")


class LandscapeOut(BaseModel):
    id: str
    robot_id: str | None
    method: str
    x: LandscapeAxisOut
    y: LandscapeAxisOut
    fixed: dict[str, float] = Field(description="the method's other parameters")
    objective_b: list[list[float | None]] = Field(description="B per cell [x index][y index]; null where infeasible")
    feasible: list[list[bool]] = Field(description="every task's plan finite and within the joint speed limit")
    max_joint_speed_deg_s: list[list[float | None]] = Field(
        description="the largest joint speed over the tasks, deg/s (null where a plan diverged)"
    )
    best_params: dict[str, float] = Field(description="the cell with the smallest B (empty if none is feasible)")
    best_objective_b: float | None
    feasible_fraction: float = Field(description="share of feasible cells, 0 to 1")
    marks: LandscapeMarks | None
    evaluations: int = Field(description="plans run: cells x tasks")
    elapsed_s: float = Field(description="s, computing the grid")
    created_at: datetime
    links: LandscapeLinks
