"""What every request and response body shares: bounded numbers, closed vocabularies as named
enums, the strict :class:`Input` and the always-complete :class:`Output` base classes, and a
request's choice of robot (:class:`OneRobot`). SI units; angles in degrees only where a name ends
in ``_deg`` (or ``_deg_s``); quaternions are ``[w, x, y, z]``.

Joint positions come in two index-aligned lists, one per unit: ``..._deg`` holds the revolute
joints (deg) and ``..._m`` the prismatic ones (m), each with null at the joints of the other
type (a list may be left out when the robot has no joint of its unit). So an all-revolute robot
keeps its plain ``q0_deg`` list."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    field_validator,
)
from typing_extensions import TypeAliasType

from engine.bounds import MAX_EFFORT, MAX_INERTIA, MAX_JOINT_LIMIT, MAX_JOINTS, MAX_LENGTH_M, MAX_MASS_KG
from engine.errors import ParameterError
from engine.metrics import AGGREGATIONS, ATTITUDE_TERMS, DET_UNITS, SINGULAR_VALUE_UNITS, check_weights
from engine.model import JOINT_TYPES, RobotModel
from engine.paths import PROFILES
from engine.redundancy import SECONDARY_OBJECTIVES
from engine.trajectory import PAPER_Q0_DEG, PAPER_TARGET_POSITION, PAPER_TARGET_QUATERNION, TRACKS
from engine.tuning import TASK_AGGREGATIONS

# Every number in a request is bounded (an overflow inside the engine is ruled out by the schema);
# a robot's bounds are the engine's own (engine.bounds), so its models are within them too.
MAX_ANGLE_DEG = 36_000.0  # a hundred turns
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
#: Joint positions of one unit, index-aligned with the robot's joints (null: a joint of the other
#: unit): revolute joints' angles in degrees (:data:`JointValues`), prismatic joints' displacements
#: in metres (:data:`JointLengths`).
JointValues = Annotated[list[AngleDeg | None], Field(min_length=1, max_length=MAX_JOINTS)]
JointLengths = Annotated[list[Length | None], Field(min_length=1, max_length=MAX_JOINTS)]
LimitValue = Annotated[float, Field(ge=-MAX_JOINT_LIMIT, le=MAX_JOINT_LIMIT)]

#: A stored plan's, job's or landscape's id: 32 lowercase hex digits.
ID_REGEX = "[0-9a-f]{32}"
ID_PATTERN = f"^{ID_REGEX}$"
EffortLimit = Annotated[float, Field(gt=0, le=MAX_EFFORT)]

__all__ = ["DET_UNITS", "SINGULAR_VALUE_UNITS"]  # the engine's unit texts, re-used by the schemas


def vocabulary(name: str, values: Iterable[str]) -> Any:
    """A closed vocabulary as a named schema (an enum class in generated clients), built from the
    engine's own names (so the two cannot drift). A Literal, not an enum: strict validation of a
    stored request (a dict) accepts the plain strings."""
    return TypeAliasType(name, Literal[tuple(values)])


# Closed vocabularies, each a named schema (an enum class in generated clients), as the engine
# defines them (checked here so the two cannot drift). Literals, not enums: strict validation of
# a stored request (a dict) accepts the plain strings.
AggregationName = TypeAliasType("AggregationName", Literal["max", "rms", "final"])
AttitudeTermName = TypeAliasType("AttitudeTermName", Literal["angle", "eq18"])
TaskAggregationName = TypeAliasType("TaskAggregationName", Literal["mean", "max"])
TimeProfile = TypeAliasType("TimeProfile", Literal["trapezoidal", "quintic"])
JobStatus = TypeAliasType("JobStatus", Literal["queued", "running", "succeeded", "failed", "cancelled"])
JointType = TypeAliasType("JointType", Literal["revolute", "prismatic"])
JointUnit = TypeAliasType("JointUnit", Literal["deg", "m"])
TrackedQuantity = TypeAliasType("TrackedQuantity", Literal["pose", "position"])
if TYPE_CHECKING:
    SecondaryObjectiveName = str
else:  # the schema's name is the API's (a client's enum), the variable's tells it from the engine's objective
    SecondaryObjectiveName = vocabulary("SecondaryObjective", SECONDARY_OBJECTIVES)
assert set(get_args(AggregationName.__value__)) == set(AGGREGATIONS)
assert set(get_args(AttitudeTermName.__value__)) == set(ATTITUDE_TERMS)
assert set(get_args(TaskAggregationName.__value__)) == set(TASK_AGGREGATIONS)
assert set(get_args(TimeProfile.__value__)) == set(PROFILES)
assert list(get_args(JointType.__value__)) == list(JOINT_TYPES)
assert set(get_args(TrackedQuantity.__value__)) == set(TRACKS)
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


PAPER_TASK_EXAMPLE: dict[str, Any] = {
    "q0_deg": list(PAPER_Q0_DEG),
    "target_position_m": list(PAPER_TARGET_POSITION),
    "target_attitude_quaternion": list(PAPER_TARGET_QUATERNION),
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


class EngineName:
    """``Annotated`` marker of an API field whose engine name is not its name without the unit
    suffix (see :meth:`Input.locate`)."""

    __slots__ = ("name",)

    def __init__(self, name: str) -> None:
        self.name = name


#: Unit suffixes of API field names, longest first: ``duration_s`` is the engine's ``duration``.
UNIT_SUFFIXES = ("_deg_s2", "_m_s2", "_deg_s", "_m_s", "_quaternion", "_deg", "_rad", "_m", "_s")


def engine_name(api_name: str) -> str:
    """The engine's name of an API field by the naming convention (its unit suffix dropped)."""
    for suffix in UNIT_SUFFIXES:
        if api_name.endswith(suffix) and len(api_name) > len(suffix):
            return api_name[: -len(suffix)]
    return api_name


def dotted_path(loc: Sequence[Any]) -> str:
    """``["links", 2, "inertia"]`` -> ``links[2].inertia`` (the inverse of :func:`field_path`)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def field_path(field: str) -> list[str | int]:
    """``links[2].inertia`` -> ``["links", 2, "inertia"]``."""
    path: list[str | int] = []
    for part in field.replace("]", "").split("."):
        name, _, index = part.partition("[")
        path.append(name)
        for i in index.split("[") if index else ():
            path.append(int(i))
    return path


class Input(BaseModel):
    """A request body, strictly typed: every number must be finite (NaN and infinities, which
    JSON parsers accept as ``NaN``/``Infinity`` literals or overflow to, are rejected with the
    field path), no text for a number and no number for a boolean, no unknown fields, no NUL
    characters in text.

    Each schema converts itself to the engine's objects (a ``to_engine`` method); the engine names
    what it refuses with its own field names (``ParameterError(field, reason)``), and
    :meth:`locate` turns such a name into the API location of the field it came from, by the
    names the schema declares: an API field's engine name is its name without the unit suffix
    (``duration_s`` -> ``duration``) unless an :class:`EngineName` marker says otherwise."""

    model_config = ConfigDict(allow_inf_nan=False, strict=True, extra="forbid")

    @field_validator("*", mode="after")
    @classmethod
    def _text_without_nul(cls, value: Any) -> Any:
        return _no_nul(value)

    @classmethod
    @functools.cache
    def engine_fields(cls) -> dict[str, tuple[str, str]]:
        """Engine name (and API name) -> (API name, attribute) of each field."""
        out: dict[str, tuple[str, str]] = {}
        for attr, info in cls.model_fields.items():
            api = info.alias or attr
            marker = next((m for m in info.metadata if isinstance(m, EngineName)), None)
            out.setdefault(marker.name if marker else engine_name(api), (api, attr))
        for attr, info in cls.model_fields.items():
            out.setdefault(info.alias or attr, (info.alias or attr, attr))
        return out

    def locate(self, field: str | Sequence[str | int]) -> list[str | int]:
        """The API location, relative to this body, of the engine's field ``field`` (a dotted
        path such as ``waypoints[2].attitude``); as deep as the schema knows it."""
        parts = field_path(field) if isinstance(field, str) else list(field)
        if not parts or not isinstance(parts[0], str):
            return []
        found = self.engine_fields().get(parts[0])
        if found is None:  # a name the schema does not declare: an extra field it let through, or nothing
            return [parts[0]] if self.model_extra and parts[0] in self.model_extra else []
        api, attr = found
        return [api, *_descend(getattr(self, attr), parts[1:])]


def _descend(value: Any, parts: list[str | int]) -> list[str | int]:
    out: list[str | int] = []
    while parts:
        head = parts[0]
        if isinstance(head, int):
            out.append(head)
            value = value[head] if isinstance(value, list) and 0 <= head < len(value) else None
            parts = parts[1:]
        elif isinstance(value, Input):
            return out + value.locate(parts)
        else:
            break
    return out


API_LOCATION = "api_location"


@contextmanager
def located(schema: Input | None, *prefix: str | int) -> Iterator[None]:
    """Run engine code on what ``schema`` (at ``prefix``, e.g. ``"body", "task"``) converted: a
    ``ParameterError`` it raises gets the API location of the field it names (see
    :meth:`Input.locate`), kept by the innermost context, for the one handler that answers it
    (:func:`service.errors.install`)."""
    try:
        yield
    except ParameterError as exc:
        if getattr(exc, API_LOCATION, None) is None:
            where = schema.locate(exc.field) if schema is not None else field_path(exc.field)
            setattr(exc, API_LOCATION, [*prefix, *where])
        raise


def joint_positions(
    model: RobotModel, deg: list[float | None] | None, m: list[float | None] | None, fields: tuple[str, str]
) -> np.ndarray:
    """``q (n,)`` (rad, m) from the API's two index-aligned lists named ``fields`` (degrees for the
    revolute joints, metres for the prismatic ones, null at the other joints); the first problem
    is a ``ParameterError`` naming the API field (``q0_m[2]``)."""
    n = model.n_joints
    deg_field, m_field = fields
    for values, field in ((deg, deg_field), (m, m_field)):
        if values is not None and len(values) != n:
            raise ParameterError(field, f"expected {n} values (one per joint), got {len(values)}")
    q = np.empty(n)
    for j, link in enumerate(model.links):
        field, other = (m_field, deg_field) if link.prismatic else (deg_field, m_field)
        mine, theirs = (m, deg) if link.prismatic else (deg, m)
        kind = "prismatic (m)" if link.prismatic else "revolute (deg)"
        value = mine[j] if mine is not None else None
        if value is None:
            raise ParameterError(f"{field}[{j}]", f"joint {j + 1} ({model.joint_names[j]}) is {kind}: give it in {field}")
        if theirs is not None and theirs[j] is not None:
            raise ParameterError(f"{other}[{j}]", f"joint {j + 1} ({model.joint_names[j]}) is {kind}: null here")
        q[j] = value if link.prismatic else math.radians(value)
    return q


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
