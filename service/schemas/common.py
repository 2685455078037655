"""What every request and response body shares: bounded numbers, closed vocabularies as named
enums, the strict :class:`Input` and the always-complete :class:`Output` base classes, and a
request's choice of robot (:class:`OneRobot`). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``.

Joint positions come in two index-aligned lists, one per unit: ``..._deg`` holds the revolute
joints (deg) and ``..._m`` the prismatic ones (m), each with null at the joints of the other
type (a list may be left out when the robot has no joint of its unit). So an all-revolute robot
keeps its plain ``q0_deg`` list."""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal, get_args

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    GetJsonSchemaHandler,
    field_validator,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema
from typing_extensions import TypeAliasType

from engine.inverses import METHODS
from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, check_weights
from engine.model import JOINT_TYPES
from engine.paths import ARC_ATTITUDES, PROFILES
from engine.redundancy import SECONDARY_OBJECTIVES
from engine.spatial import matrix_to_quaternion, rpy_spacedyn_to_matrix
from engine.trajectory import PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_RPY, TRACKS
from engine.tuning import TASK_AGGREGATIONS

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


# --- methods ------------------------------------------------------------------------------


def _omitted_when_none(value: Any) -> bool:
    return value is None


def _without_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


#: The units of the singular values of the GJM (which maps joint rates, rad/s, to [v (m/s); w
#: (rad/s)]: m/rad on the linear rows, 1 on the angular rows) and of the damping parameters.
SINGULAR_VALUE_UNITS = "in the units of the GJM's singular values"


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
