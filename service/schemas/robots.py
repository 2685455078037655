"""Robots: parameter sets, URDF documents, joints, the GJM at a state."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated, Any

import numpy as np
from pydantic import ConfigDict, Field, GetJsonSchemaHandler, ValidationError, model_validator
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from engine import GJMResult, RobotModel, State
from engine.errors import ParameterError
from engine.geometry import MAX_SHAPES
from engine.spatial import FloatArray, matrix_to_quaternion, quaternion_to_matrix
from engine.trajectory import PAPER_Q0_DEG
from engine.urdf import MAX_URDF_BYTES, UrdfError, urdf_element, urdf_to_dict
from service.infra import jsonio
from service.infra.lru import Lru
from service.schemas.common import (
    DET_UNITS,
    MAX_JOINTS,
    EffortLimit,
    EngineName,
    Inertia,
    Input,
    JointLengths,
    JointType,
    JointUnit,
    JointValues,
    LimitValue,
    Mass,
    Output,
    Quaternion,
    Rotation,
    Vec3,
    _omitted_when_none,
    dotted_path,
    joint_positions,
)
from service.schemas.geometry import MESH_HULLS, BodyShapeIn, Size, Size3

# --- robots -------------------------------------------------------------------------------


class CollisionBox(Input):
    """The carrier's collision box, its edges along the carrier's axes."""

    size_m: Size3 = Field(description="edge lengths along the carrier's x, y and z axes, m")
    center_m: Vec3 | None = Field(
        default=None, description="the box's centre from the carrier's CoM, carrier frame, m (default 0)"
    )


SHAPES_FRAME = "positions and attitudes in the {body} frame, positions from its CoM"


class BaseParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the base link's name (default `base`)")
    mass: Mass
    inertia: Inertia = Field(description="kg m^2 about the base CoM, base frame")
    b: Vec3 = Field(description="m, base CoM to joint 1, base frame")
    collision_box: CollisionBox | None = Field(default=None, description="the carrier's collision box (null: none)")
    collision_shapes: list[BodyShapeIn] | None = Field(
        default=None,
        max_length=MAX_SHAPES,
        description=f"more collision shapes of the carrier, {SHAPES_FRAME.format(body='carrier')}",
    )


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
    torque_limit_n_m: EffortLimit | None = Field(
        default=None,
        description="revolute joints: the largest |torque| the joint may exert, N m (> 0; null: none); every plan's "
        "torques along its executed trajectory are checked against it and it counts in P_l of B (URDF <limit effort>)",
    )
    force_limit_n: EffortLimit | None = Field(
        default=None, description="prismatic joints: the largest |force| the joint may exert, N (> 0; null: none)"
    )
    collision_radius_m: Size | None = Field(
        default=None,
        description="the link as a capsule of this radius, m, from its joint's origin to the next joint's origin (the "
        "last link: to the end-effector point; a prismatic link: from where its joint's origin is at q = 0); null: none",
    )
    collision_shapes: list[BodyShapeIn] | None = Field(
        default=None, max_length=MAX_SHAPES, description=f"more collision shapes of the link, {SHAPES_FRAME.format(body='link')}"
    )


class EndEffectorParams(Input):
    name: str | None = Field(default=None, max_length=200, description="the end-effector frame's name")
    C_e: Rotation = Field(description="end-effector frame in the last link's frame (rotation matrix)")


MODEL_CACHE_SIZE = 64
_MODELS: Lru[bytes, RobotModel] = Lru(MODEL_CACHE_SIZE)


def model_of(parameters: dict[str, Any]) -> RobotModel:
    """The model of a parameter set, whatever its source (a request's, a URDF's, a stored robot's),
    through the one validation of robots: the schema of :class:`RobotParams` (the bounds and
    messages of a request body), then the engine's checks (:meth:`RobotModel.from_dict`: positive
    definite, physical inertias, non-zero axes, ...). The first problem is a ``ParameterError``
    naming the parameter (``links[2].inertia``). Models are immutable, so the last few are kept
    (keyed by their parameters), which spares stored robots the validation on every request."""

    def build() -> RobotModel:
        try:
            checked = RobotParams.model_validate(parameters, strict=False).model_dump(exclude_none=True)
        except ValidationError as exc:
            error = exc.errors()[0]
            raise ParameterError(dotted_path(error["loc"]) or "robot", error["msg"]) from None
        return RobotModel.from_dict(checked)

    return _MODELS.get(jsonio.dumps_sorted(parameters), build)


class RobotParams(Input):
    """A robot parameter set in the schema of the Table-1 robot (``engine/data/table1_robot.json``),
    SI units."""

    name: str = Field(min_length=1, max_length=200, description="the robot's name")
    base: BaseParams = Field(description="the free-floating base (carrier)")
    links: list[LinkParams] = Field(min_length=1, max_length=MAX_JOINTS, description="the links from the base out, one per joint")
    end_effector: EndEffectorParams | None = Field(
        default=None, description="the end-effector frame (default: the last link's frame)"
    )

    def to_engine(self) -> RobotModel:
        return model_of(self.model_dump(exclude_none=True))


def distinct_names(model: RobotModel, given: RobotParams) -> None:
    """Refuse a new parameter set (a request's: stored robots and queued jobs load as they are)
    whose frames (the base, the links, the end effector) or joints share a name, as URDF does: the
    names tell links apart in reports (a clearance pair, a joint's speed) and in the URDF export,
    which would have to rename one. The end effector may bear its link's name (the URDF import
    names it so when the last moving link is the leaf). Default names count (an unnamed
    ``links[1]`` is ``link2``); the ``ParameterError`` names a field of ``given`` (the request):
    the second of two, or the given one when the other is a default."""
    ee = model.end_effector_name
    last = len(model.links) - 1
    frames = [("base.name", model.base.name, given.base.name is not None)]
    frames += [
        (f"links[{i}].name", link.name, given.links[i].name is not None)
        for i, link in enumerate(model.links)
        if not (i == last and link.name == ee)
    ]
    frames.append(("end_effector.name", ee, given.end_effector is not None and given.end_effector.name is not None))
    joints = [(f"links[{i}].joint_name", name, given.links[i].joint_name is not None) for i, name in enumerate(model.joint_names)]
    for named in (frames, joints):
        first: dict[str, tuple[str, bool]] = {}
        for field, name, explicit in named:
            if name in first:
                other, other_explicit = first[name]
                rule = "every frame and every joint needs a name of its own"
                if explicit or not other_explicit:
                    raise ParameterError(field, f"{name!r} also names {other}: {rule}")
                raise ParameterError(other, f"{name!r} is also the default name of {field}: {rule}")
            first[name] = (field, explicit)


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

    def to_engine(self) -> RobotModel:
        """The model of the URDF: the parameter set the engine derives from it, through the same
        validation as a parameter set sent as such (:func:`model_of`); a URDF refused is a
        ``UrdfError`` naming the element (a derived parameter out of range names its link, and
        says which parameter and why in the words a parameter set would get)."""
        tool = None
        if self.tool_position_m is not None or self.tool_attitude_quaternion is not None:
            try:
                rotation = quaternion_to_matrix(self.tool_attitude_quaternion) if self.tool_attitude_quaternion else np.eye(3)
            except ValueError as exc:
                raise ParameterError("tool_attitude_quaternion", str(exc)) from None
            tool = (np.asarray(self.tool_position_m or [0.0, 0.0, 0.0], dtype=float), rotation)
        params = urdf_to_dict(
            self.urdf, end_effector_link=self.end_effector_link, tool_offset=tool, name=self.name, mesh_hulls=stored_mesh_hull
        )
        try:
            return model_of(params)
        except ParameterError as exc:
            raise UrdfError(urdf_element(params, exc.field), f"{exc.field}: {exc.reason}") from None


#: How a URDF ``<mesh>`` collision names a stored mesh (``POST /v1/meshes``).
MESH_URI = "mesh://"


def stored_mesh_hull(filename: str) -> FloatArray | None:
    """The hull of the stored mesh a URDF ``<mesh filename="mesh://<id>">`` names (None for any
    other file name: the URDF importer refuses it, saying how to name a stored mesh; a
    ``LookupError`` saying so for an id no mesh has)."""
    resolve = MESH_HULLS.get()
    if resolve is None or not filename.startswith(MESH_URI):
        return None
    try:
        return resolve(filename[len(MESH_URI) :])
    except ParameterError as exc:
        raise LookupError(f"{exc.reason}; GET /v1/meshes lists the stored ones") from None


class JointOut(Output):
    """A joint of a stored robot, with the unit of its position in the API and its limits."""

    name: str = Field(description="the joint's name")
    type: JointType = Field(description="revolute or prismatic")
    unit: JointUnit = Field(description="the unit of its position in the API: `_deg` or `_m` lists")
    lower_deg: float | None = Field(default=None, description="revolute joints: lower position limit, deg (null: unlimited)")
    upper_deg: float | None = Field(default=None, description="revolute joints: upper position limit, deg (null: unlimited)")
    lower_m: float | None = Field(default=None, description="prismatic joints: lower position limit, m (null: unlimited)")
    upper_m: float | None = Field(default=None, description="prismatic joints: upper position limit, m (null: unlimited)")
    torque_limit_n_m: float | None = Field(default=None, description="revolute joints: torque limit, N m (null: none)")
    force_limit_n: float | None = Field(default=None, description="prismatic joints: force limit, N (null: none)")


def _degrees(value: float) -> float | None:
    return math.degrees(value) if math.isfinite(value) else None


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def joints_of(model: RobotModel) -> tuple[list[JointOut], list[str]]:
    """The joints with their API units and limits, and notes on the joints without limits and on
    revolute limits that look like degrees given as radians."""
    joints, unlimited, turns = [], [], []
    for name, link in zip(model.joint_names, model.links, strict=True):
        effort = _finite(link.effort_limit)  # N m or N
        if link.prismatic:
            joints.append(
                JointOut(
                    name=name,
                    type="prismatic",
                    unit="m",
                    lower_m=_finite(link.lower),
                    upper_m=_finite(link.upper),
                    force_limit_n=effort,
                )
            )
        else:
            joints.append(
                JointOut(
                    name=name,
                    type="revolute",
                    unit="deg",
                    lower_deg=_degrees(link.lower),
                    upper_deg=_degrees(link.upper),
                    torque_limit_n_m=effort,
                )
            )
        if not (math.isfinite(link.lower) and math.isfinite(link.upper)):
            unlimited.append(name)
        elif not link.prismatic and link.upper - link.lower > 4.0 * math.pi:
            turns.append(f"{name} ({link.lower:g} to {link.upper:g} rad)")
    notes = []
    if turns:
        notes.append(
            f"joint(s) {', '.join(turns)} may turn more than twice between their limits: a parameter set's limits are in "
            "radians (-170 deg is -2.967), and were taken as given"
        )
    if unlimited:
        notes.append(
            f"joint(s) {', '.join(unlimited)} have no position limit on at least one side (a continuous joint, a revolute "
            "joint without <limit>, or no lower/upper): treated as unlimited there"
        )
    return joints, notes


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

    @classmethod
    def from_engine(
        cls, robot_id: str, name: str, preset: bool, parameters: dict[str, Any], created_at: datetime, model: RobotModel
    ) -> RobotOut:
        """A stored robot: its row's fields and its model (the parameters were validated on the
        way in and normalised since, so they are not validated strictly again)."""
        joints, notes = joints_of(model)
        return cls.model_validate(
            {
                "id": robot_id,
                "name": name,
                "preset": preset,
                "n_joints": model.n_joints,
                "parameters": parameters,
                "joints": joints,
                "notes": notes,
                "created_at": created_at,
            },
            strict=False,
        )


class RobotList(Output):
    items: list[RobotOut] = Field(description="this page of robots, oldest first")
    total: int = Field(description="number of robots stored")


class JacobianRequest(Input):
    """A state of the robot: its joint positions and the base pose."""

    joint_angles_deg: Annotated[JointValues | None, EngineName("q")] = Field(
        default=None, description="revolute joint angles, deg (null at prismatic joints)", examples=[list(PAPER_Q0_DEG)]
    )
    joint_displacements_m: JointLengths | None = Field(
        default=None, description="prismatic joint positions, m (null at revolute joints)"
    )
    base_position_m: Vec3 | None = Field(default=None, description="base CoM in world, m (default origin)")
    base_attitude_quaternion: Quaternion | None = Field(default=None, description="base attitude [w, x, y, z] (default identity)")

    def to_engine(self, model: RobotModel) -> State:
        """The engine's state of ``model`` (errors name ``q``, ``base_position``, ``base_attitude``)."""
        q = joint_positions(
            model, self.joint_angles_deg, self.joint_displacements_m, ("joint_angles_deg", "joint_displacements_m")
        )
        try:
            attitude = quaternion_to_matrix(self.base_attitude_quaternion) if self.base_attitude_quaternion else np.eye(3)
        except ValueError as exc:
            raise ParameterError("base_attitude", str(exc)) from None
        return State(q, np.asarray(self.base_position_m if self.base_position_m else np.zeros(3), dtype=float), attitude)


class JacobianOut(Output):
    gjm: list[list[float]] = Field(description="6 x n generalized Jacobian: joint rates (rad/s) to [v (m/s); w (rad/s)]")
    singular_values: list[float] = Field(
        description="singular values of the GJM, descending (units of the GJM: m/rad for the linear rows, 1 for the angular)"
    )
    determinant: float | None = Field(description=f"det of the GJM, {DET_UNITS}; null unless it is square")
    manipulability: float = Field(
        description=f"the product of the singular values (sqrt(det(J J^T)) for 6 or more joints), {DET_UNITS}; with fewer "
        "than 6 joints it mixes the rows' units and has none of its own"
    )
    condition_number: float | None = Field(
        description="largest over smallest singular value (dimensionless); null if the GJM is singular"
    )
    ee_position_m: list[float] = Field(description="end-effector position, m (world)")
    ee_attitude_quaternion: list[float] = Field(description="end-effector attitude [w, x, y, z] (end effector -> world)")

    @classmethod
    def from_engine(cls, gjm: GJMResult) -> JacobianOut:
        def number(value: float | None) -> float | None:
            return float(value) if value is not None and math.isfinite(value) else None

        return cls(
            gjm=gjm.J_g.tolist(),
            singular_values=gjm.singular_values.tolist(),
            determinant=number(gjm.determinant),
            manipulability=gjm.manipulability,
            condition_number=number(gjm.condition_number),
            ee_position_m=gjm.ee_position.tolist(),
            ee_attitude_quaternion=matrix_to_quaternion(gjm.ee_attitude).tolist(),
        )


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

    # Optional but not nullable: left out when not used (a null is refused like any wrong type).
    # Left out of a dump when not given, too (a request echoed in a response has only the one given).
    robot_id: str = Field(  # type: ignore[assignment]
        default=None,
        min_length=1,
        max_length=64,
        exclude_if=_omitted_when_none,
        description="a stored robot; or give `robot` inline (one of the two)",
    )
    robot: RobotParams = Field(  # type: ignore[assignment]
        default=None, exclude_if=_omitted_when_none, description="inline robot parameters (instead of robot_id)"
    )

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
