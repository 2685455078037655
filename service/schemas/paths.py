"""Path types of a task, each a schema that owns its parameters and its conversion to the
engine's path (:mod:`engine.paths`); the discriminated union :data:`PathIn` is built from the
schemas declared here (:class:`PathSchema` subclasses), so a new path type is its engine module
and its schema.

What a path takes from its task (the timing ``duration_s``, ``ramp_time_s``, ``profile``, and a
line's target pose) is given to :meth:`PathSchema.to_engine` as :class:`PathContext`."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, NamedTuple, Union

import numpy as np
from pydantic import AfterValidator, Field

from engine.errors import ParameterError
from engine.paths import ARC_ATTITUDES, MAX_PASSES, MAX_WAYPOINTS, PATH_TYPES, Path, SpeedLimits, make_path
from engine.spatial import FloatArray, quaternion_to_matrix
from engine.trajectory import MAX_DURATION_S
from service.schemas.common import Input, vocabulary

UNIT_QUATERNION_TOLERANCE = 1e-6
#: Coordinates of path geometry (m): far beyond any robot's reach, small enough to stay finite.
MAX_COORDINATE_M = 1e4
#: The duration of a line or an arc when the task gives none, s.
DEFAULT_DURATION_S = 15.0

if TYPE_CHECKING:
    ArcAttitude = str
else:
    ArcAttitude = vocabulary("ArcAttitude", ARC_ATTITUDES)


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


def rotation(quaternion: list[float], field: str) -> FloatArray:
    """The rotation matrix of an API quaternion; a quaternion the engine refuses names ``field``."""
    try:
        return quaternion_to_matrix(np.asarray(quaternion, dtype=float))
    except ValueError as exc:
        raise ParameterError(field, str(exc)) from None


class PathContext(NamedTuple):
    """What a task says about its path: ``duration`` (s, None: the path's own timing; never None
    for a line or an arc, whose default ``TaskIn`` fills in), ``ramp_time`` (s),
    ``profile``, and a line's target pose (m; a rotation matrix, None when not given) and what
    the task tracks."""

    duration: float | None
    ramp_time: float
    profile: str
    target_position: FloatArray | None
    target_attitude: FloatArray | None
    tracks: str


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

    def limits(self) -> SpeedLimits:
        return SpeedLimits(
            self.max_speed_m_s,
            math.radians(self.max_angular_speed_deg_s),
            self.max_acceleration_m_s2,
            math.radians(self.max_angular_acceleration_deg_s2),
        )


class PathSchema(Input):
    """A path type's request schema: its ``type`` tag (the engine's path kind) and its parameters."""

    kind: ClassVar[str]
    #: s: the duration a task without ``duration_s`` has on this path (None: the path's own timing,
    #: which a stored request leaves null so that a rerun with other speeds retimes it)
    default_duration_s: ClassVar[float | None] = None
    #: Whether the path keeps its own timing when the task gives no ``duration_s`` (it is then
    #: refused if that exceeds the longest duration allowed).
    timed_by_itself: ClassVar[bool] = False
    types: ClassVar[dict[str, type[PathSchema]]] = {}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "kind" in cls.__dict__:
            PathSchema.types[cls.kind] = cls

    def spec(self, start_attitude: FloatArray, task: PathContext) -> dict[str, Any]:
        """The engine's keyword arguments of this path (:func:`engine.paths.make_path`)."""
        raise NotImplementedError

    def to_engine(self, start_position: FloatArray, start_attitude: FloatArray, task: PathContext) -> Path:
        """The engine's path from the start pose; errors name the engine's fields (see :meth:`Input.locate`)."""
        if self.kind != "line":
            for name, value in (("target_position", task.target_position), ("target_attitude", task.target_attitude)):
                if value is not None:
                    raise ParameterError(name, f"only for line paths (the {self.kind} path sets its own poses)")
        path = make_path(self.kind, start_position, start_attitude, **self.spec(start_attitude, task))
        if self.timed_by_itself and task.duration is None and path.duration > MAX_DURATION_S:
            raise ParameterError(
                "path",
                f"the path takes {path.duration:.6g} s at its speeds (or durations), more than the {MAX_DURATION_S:g} s "
                "allowed: raise its speeds or give duration_s",
            )
        return path

    def timing(self, path: Path) -> dict[str, float]:
        """The task fields besides ``duration_s`` that describe ``path``'s timing (for a request
        that plans a retimed path again)."""
        return {}


class LinePathIn(PathSchema):
    """The paper's straight line from the start pose to the task's `target_position_m` and
    `target_attitude_quaternion`, the attitude rotating about one fixed axis; timed by the task's
    `duration_s` (default 15), `profile` and `ramp_time_s`."""

    kind: ClassVar[str] = "line"
    default_duration_s: ClassVar[float | None] = DEFAULT_DURATION_S
    type: Literal["line"] = Field(default="line", description="the path type")

    def spec(self, start_attitude: FloatArray, task: PathContext) -> dict[str, Any]:
        if task.target_position is None:
            raise ParameterError("target_position", "required for a line path")
        if task.target_attitude is None and task.tracks == "pose":
            raise ParameterError("target_attitude", "required for a pose task on a line path (a position task may leave it out)")
        # not tracked by a position task: the start attitude is carried along for the figures
        return {
            "target_position": task.target_position,
            "target_attitude": start_attitude if task.target_attitude is None else task.target_attitude,
            "duration": task.duration,  # filled in by TaskIn when left out
            "ramp_time": task.ramp_time,
            "profile": task.profile,
        }

    def timing(self, path: Path) -> dict[str, float]:
        return {"ramp_time_s": float(path.ramp_time)}  # type: ignore[attr-defined]


class WaypointsPathIn(MoveLimits, PathSchema):
    """Poses visited in order from the start pose: each segment a straight line and an SO(3)
    geodesic on one quintic time law, rest to rest (the path passes through every pose with
    continuous velocity and acceleration). Timed by the limits, or by `segment_durations_s`;
    the task's `duration_s`, if given, rescales the whole path to it."""

    kind: ClassVar[str] = "waypoints"
    timed_by_itself: ClassVar[bool] = True
    type: Literal["waypoints"] = Field(description="the path type")
    waypoints: list[PoseIn] = Field(min_length=1, max_length=MAX_WAYPOINTS, description="poses to visit, in order")
    segment_durations_s: list[Annotated[float, Field(gt=0, le=MAX_DURATION_S)]] | None = Field(
        default=None, description="s, one per waypoint (the segment that ends there); replaces the limits"
    )

    def spec(self, start_attitude: FloatArray, task: PathContext) -> dict[str, Any]:
        return {
            "positions": np.array([w.position_m for w in self.waypoints], dtype=float),
            "attitudes": np.array(
                [rotation(w.attitude_quaternion, f"waypoints[{i}].attitude") for i, w in enumerate(self.waypoints)]
            ),
            "limits": self.limits(),
            "segment_durations": None if self.segment_durations_s is None else np.array(self.segment_durations_s),
            "duration_override": task.duration,
        }


class ArcPathIn(PathSchema):
    """A circular arc from the start position: either `centre_m`, `axis` and `angle_deg` (the
    start turned about the line through the centre along the axis, right hand), or
    `via_position_m` and `end_position_m` (the circle through the start, via and end points).
    Timed like a line by the task's `duration_s` (default 15), `profile` and `ramp_time_s`."""

    kind: ClassVar[str] = "arc"
    default_duration_s: ClassVar[float | None] = DEFAULT_DURATION_S
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

    def spec(self, start_attitude: FloatArray, task: PathContext) -> dict[str, Any]:
        law = {
            "attitude": self.attitude,
            "duration": task.duration,  # filled in by TaskIn when left out
            "ramp_time": task.ramp_time,
            "profile": task.profile,
        }
        three_points = {"via_position_m": self.via_position_m, "end_position_m": self.end_position_m}
        centred = {"centre_m": self.centre_m, "axis": self.axis, "angle_deg": self.angle_deg}
        if any(v is not None for v in three_points.values()):
            for name, value in centred.items():
                if value is not None:
                    raise ParameterError(name, "give either centre_m, axis and angle_deg or via_position_m and end_position_m")
            for name, value in three_points.items():
                if value is None:
                    raise ParameterError(name, "required with the other of via_position_m and end_position_m")
            return {"via_position": self.via_position_m, "end_position": self.end_position_m, **law}
        for name, value in centred.items():
            if value is None:
                raise ParameterError(name, "required: give centre_m, axis and angle_deg (or via_position_m and end_position_m)")
        assert self.angle_deg is not None
        return {"centre": self.centre_m, "axis": self.axis, "angle": math.radians(self.angle_deg), **law}

    def timing(self, path: Path) -> dict[str, float]:
        return {"ramp_time_s": float(path.ramp_time)}  # type: ignore[attr-defined]


class RasterPathIn(MoveLimits, PathSchema):
    """A boustrophedon scan of the rectangle `corner_m + x scan_edge_m + y step_edge_m` (x, y in
    [0, 1]) from the side of its normal `n = scan_edge x step_edge` (normalised): the end
    effector at `standoff_m` along n, the sensor axis pointing at the patch (along -n). Passes run
    along the scan edge every `line_spacing_m` along the step edge, alternating direction, joined
    outside the patch by turns of `turn_radius_m`; the whole scan at `scan_speed_m_s` with
    ramps of `scan_acceleration_m_s2` at its ends, after a quintic approach (the limits) from the
    start pose. The task's `duration_s`, if given, rescales the whole path to it."""

    kind: ClassVar[str] = "raster"
    timed_by_itself: ClassVar[bool] = True
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

    def spec(self, start_attitude: FloatArray, task: PathContext) -> dict[str, Any]:
        return {
            "corner": self.corner_m,
            "scan_edge": self.scan_edge_m,
            "step_edge": self.step_edge_m,
            "line_spacing": self.line_spacing_m,
            "standoff": self.standoff_m,
            "scan_speed": self.scan_speed_m_s,
            "scan_acceleration": self.scan_acceleration_m_s2,
            "turn_radius": self.turn_radius_m,
            "sensor_axis": self.sensor_axis,
            "approach": self.limits(),
            "pass_index": self.pass_index,
            "duration_override": task.duration,
        }


assert set(PathSchema.types) == set(PATH_TYPES), "every engine path type has its schema, and no other"
if TYPE_CHECKING:
    PathIn = PathSchema
    PathType = str
else:
    PathIn = Annotated[Union[tuple(PathSchema.types.values())], Field(discriminator="type")]  # noqa: UP007
    PathType = Literal[tuple(PathSchema.types)]
