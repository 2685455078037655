"""Robots: stored parameter sets (given as such, or derived from a URDF), their URDF, and the
generalized Jacobian at a state."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from fastapi import APIRouter, Body, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from engine import RobotModel, State, generalized_jacobian
from engine.errors import ParameterError
from engine.spatial import matrix_to_quaternion, quaternion_to_matrix
from service.convert import clean, joint_positions, robot_model, urdf_model
from service.deps import Limit, Offset, RobotId, SessionDep, SessionRoute, SettingsDep, load_row
from service.errors import ApiValidationError, ConflictError, responses
from service.infra import jsonio
from service.infra.quota import check_quota
from service.models import Robot
from service.schemas.robots import JacobianOut, JacobianRequest, JointOut, RobotList, RobotOut, RobotParams, RobotUrdfIn

router = APIRouter(prefix="/v1/robots", tags=["robots"], route_class=SessionRoute)


def _degrees(value: float) -> float | None:
    return math.degrees(value) if math.isfinite(value) else None


def _metres(value: float) -> float | None:
    return value if math.isfinite(value) else None


def joints_out(model: RobotModel) -> tuple[list[JointOut], list[str]]:
    """The joints with their API units and limits, and notes on the joints without limits."""
    joints, unlimited = [], []
    for name, link in zip(model.joint_names, model.links, strict=True):
        if link.prismatic:
            joints.append(
                JointOut(name=name, type="prismatic", unit="m", lower_m=_metres(link.lower), upper_m=_metres(link.upper))
            )
        else:
            joints.append(
                JointOut(name=name, type="revolute", unit="deg", lower_deg=_degrees(link.lower), upper_deg=_degrees(link.upper))
            )
        if not (math.isfinite(link.lower) and math.isfinite(link.upper)):
            unlimited.append(name)
    notes = []
    if unlimited:
        notes.append(
            f"joint(s) {', '.join(unlimited)} have no position limit on at least one side (a continuous joint, a revolute "
            "joint without <limit>, or no lower/upper): treated as unlimited there"
        )
    return joints, notes


def robot_out(robot: Robot) -> RobotOut:
    joints, notes = joints_out(robot_model(robot.parameters))
    # the stored parameters were validated on the way in (and normalised since): not strictly again
    return RobotOut.model_validate(
        {
            "id": robot.id,
            "name": robot.name,
            "preset": robot.preset,
            "n_joints": len(robot.parameters.get("links", [])),
            "parameters": robot.parameters,
            "joints": joints,
            "notes": notes,
            "created_at": robot.created_at,
        },
        strict=False,
    )


def load_robot(session: Session, robot_id: str) -> Robot:
    return load_row(session, Robot, robot_id, "robot")


@router.get(
    "",
    operation_id="list_robots",
    response_model=RobotList,
    summary="List robots",
    description="Stored robots, oldest first (the `table1` preset first), `limit` at a time from `offset`; "
    "`total` counts them all.",
    responses=responses(422),
)
def list_robots(session: SessionDep, limit: Limit = 50, offset: Offset = 0) -> RobotList:
    total = session.scalar(select(func.count()).select_from(Robot)) or 0
    rows = session.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(limit).offset(offset)).all()
    return RobotList(items=[robot_out(r) for r in rows], total=total)


def _schema_ref(model: type) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{model.__name__}"}


CREATE_ROBOT_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {
                # RobotUrdfIn is added to the document's components by service.openapi (BODY_MODELS)
                "schema": {"oneOf": [_schema_ref(RobotParams), _schema_ref(RobotUrdfIn)]},
                "examples": {
                    "urdf": {
                        "summary": "a URDF robot (the URDF as text in the `urdf` field)",
                        "value": {"urdf": "<robot name='my-arm'>...</robot>", "end_effector_link": "tool0"},
                    }
                },
            }
        },
    }
}


def _validated(model: type[RobotParams] | type[RobotUrdfIn], body: dict[str, Any]) -> Any:
    """``body`` validated as ``model``, errors under ``body`` like FastAPI's own."""
    try:
        return model.model_validate(body)
    except ValidationError as exc:
        raise RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in exc.errors()]) from None


@router.post(
    "",
    operation_id="create_robot",
    response_model=RobotOut,
    status_code=status.HTTP_201_CREATED,
    summary="Store a robot: a parameter set (schema of robot-table1.yaml, SI units) or a URDF (JSON field `urdf`)",
    description="The body is either a parameter set (`RobotParams`) or a URDF document as text in the field `urdf`, "
    "with `end_effector_link` and an optional tool offset (`RobotUrdfIn`). A URDF robot is stored as the parameter set "
    "derived from it (shown in the response); a URDF the service cannot use is a 422 whose `element` names the URDF "
    "element at fault. The parameters are checked as the engine needs them (masses positive, inertias symmetric "
    "positive definite and physical, joint axes and rotations valid; a 422 names the field, e.g. "
    "`body.links[2].inertia`) and the joint axes normalised; 201 with the robot and its `Location`.",
    responses=responses(422),
    openapi_extra=CREATE_ROBOT_BODY,
)
def create_robot(session: SessionDep, settings: SettingsDep, response: Response, body: dict[str, Any] = Body(...)) -> RobotOut:
    if "urdf" in body:
        model = urdf_model(_validated(RobotUrdfIn, body))
    else:
        params = _validated(RobotParams, body)
        model = robot_model(params.model_dump(exclude_none=True), ("body",))
    parameters = clean(model.to_dict())
    check_quota(session, settings.storage_quota_bytes, len(jsonio.dumps(parameters)))
    robot = Robot(name=model.name, parameters=parameters, preset=False)
    session.add(robot)
    session.commit()  # before the response goes out: a client's next request must see it
    response.headers["Location"] = f"/v1/robots/{robot.id}"
    return robot_out(robot)


@router.get(
    "/{robot_id}",
    operation_id="get_robot",
    response_model=RobotOut,
    summary="Get a robot",
    description="A stored robot and its parameter set; `table1` is the paper's Table-1 robot.",
    responses=responses(404),
)
def get_robot(robot_id: RobotId, session: SessionDep) -> RobotOut:
    return robot_out(load_robot(session, robot_id))


@router.get(
    "/{robot_id}/urdf",
    operation_id="get_robot_urdf",
    summary="The robot as a URDF document (reads back to the same model here and in Pinocchio)",
    description="The stored robot as URDF text (SI units; revolute, continuous and prismatic joints with their "
    "limits): `POST /v1/robots` with it in `urdf` (and its end-effector link) stores the same model again.",
    response_class=Response,
    responses={
        200: {"description": "URDF (XML)", "content": {"application/xml": {"schema": {"type": "string"}}}},
        **responses(404),
    },
)
def get_robot_urdf(robot_id: RobotId, session: SessionDep) -> Response:
    model = robot_model(load_robot(session, robot_id).parameters)
    return Response(model.to_urdf(), media_type="application/xml")


@router.delete(
    "/{robot_id}",
    operation_id="delete_robot",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a robot (presets cannot be deleted)",
    description="204 once deleted. Stored plans keep their results (their `robot_id` becomes null); a queued tuning job "
    "for the robot fails when a worker takes it. Deleting a preset is a 409.",
    responses=responses(404, 409),
)
def delete_robot(robot_id: RobotId, session: SessionDep) -> Response:
    robot = load_robot(session, robot_id)
    if robot.preset:
        raise ConflictError(f"robot {robot_id!r} is a preset and cannot be deleted")
    session.delete(robot)
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)


#: Engine state fields and their names in the request body.
STATE_FIELDS = {"q": "joint_angles_deg", "base_position": "base_position_m", "base_attitude": "base_attitude_quaternion"}
JOINT_FIELDS = ("joint_angles_deg", "joint_displacements_m")


@router.post(
    "/{robot_id}/jacobian",
    operation_id="compute_jacobian",
    response_model=JacobianOut,
    summary="Generalized Jacobian (GJM) and end-effector pose at a state",
    description="The GJM of the free-floating robot (the base's reaction included, zero momentum) at the joint angles "
    "and base pose given, with its singular values, determinant, manipulability and condition number, and the "
    "end-effector pose. Nothing is stored.",
    responses=responses(404, 422),
)
def compute_jacobian(robot_id: RobotId, body: JacobianRequest, session: SessionDep) -> JacobianOut:
    model = robot_model(load_robot(session, robot_id).parameters)
    try:
        attitude = quaternion_to_matrix(body.base_attitude_quaternion) if body.base_attitude_quaternion else np.eye(3)
    except ValueError as exc:
        loc = ["body", "base_attitude_quaternion"]
        raise ApiValidationError(f"base_attitude_quaternion: {exc}", [{"loc": loc, "msg": str(exc)}]) from None
    q = joint_positions(model, body.joint_angles_deg, body.joint_displacements_m, JOINT_FIELDS, ("body",))
    try:
        state = State(
            q,
            np.asarray(body.base_position_m if body.base_position_m else np.zeros(3), dtype=float),
            attitude,
        )
        gjm = generalized_jacobian(model, state)
    except ParameterError as exc:
        field = STATE_FIELDS.get(exc.field, exc.field)
        raise ApiValidationError(f"{field}: {exc.reason}", [{"loc": ["body", field], "msg": exc.reason}]) from None
    return JacobianOut(
        **clean(
            {
                "gjm": gjm.J_g,
                "singular_values": gjm.singular_values,
                "determinant": gjm.determinant,
                "manipulability": gjm.manipulability,
                "condition_number": gjm.condition_number,
                "ee_position_m": gjm.ee_position,
                "ee_attitude_quaternion": matrix_to_quaternion(gjm.ee_attitude),
            }
        )
    )
