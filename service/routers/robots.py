"""Robots: stored parameter sets and the generalized Jacobian at a state."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Query, Response, status
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from engine import State, generalized_jacobian
from engine.errors import ParameterError
from engine.spatial import matrix_to_quaternion, quaternion_to_matrix
from service import jsonio
from service.convert import clean, robot_model
from service.deps import SessionDep, SessionRoute, SettingsDep
from service.errors import MAX_OFFSET, ApiValidationError, ConflictError, NotFoundError, responses
from service.models import Robot
from service.quota import check_quota
from service.schemas import JacobianOut, JacobianRequest, RobotList, RobotOut, RobotParams

router = APIRouter(prefix="/v1/robots", tags=["robots"], route_class=SessionRoute)


def robot_out(robot: Robot) -> RobotOut:
    return RobotOut(
        id=robot.id,
        name=robot.name,
        preset=robot.preset,
        n_joints=len(robot.parameters.get("links", [])),
        parameters=robot.parameters,
        created_at=robot.created_at,
    )


def load_robot(session: Session, robot_id: str) -> Robot:
    robot = session.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError("robot", robot_id)
    return robot


@router.get("", operation_id="list_robots", response_model=RobotList, summary="List robots", responses=responses(422))
def list_robots(
    session: SessionDep, limit: int = Query(50, ge=1, le=500), offset: int = Query(0, ge=0, le=MAX_OFFSET)
) -> RobotList:
    total = session.scalar(select(func.count()).select_from(Robot)) or 0
    rows = session.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(limit).offset(offset)).all()
    return RobotList(items=[robot_out(r) for r in rows], total=total)


@router.post(
    "",
    operation_id="create_robot",
    response_model=RobotOut,
    status_code=status.HTTP_201_CREATED,
    summary="Store a robot parameter set (schema of robot-table1.yaml, SI units)",
    responses=responses(422),
)
def create_robot(body: RobotParams, session: SessionDep, settings: SettingsDep, response: Response) -> RobotOut:
    model = robot_model(body.model_dump(exclude_none=True), ("body",))
    parameters = clean(model.to_dict())
    check_quota(session, settings.storage_quota_bytes, len(jsonio.dumps(parameters)))
    robot = Robot(name=model.name, parameters=parameters, preset=False)
    session.add(robot)
    session.commit()  # before the response goes out: a client's next request must see it
    response.headers["Location"] = f"/v1/robots/{robot.id}"
    return robot_out(robot)


@router.get("/{robot_id}", operation_id="get_robot", response_model=RobotOut, summary="Get a robot", responses=responses(404))
def get_robot(robot_id: str, session: SessionDep) -> RobotOut:
    return robot_out(load_robot(session, robot_id))


@router.delete(
    "/{robot_id}",
    operation_id="delete_robot",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a robot (presets cannot be deleted)",
    responses=responses(404, 409),
)
def delete_robot(robot_id: str, session: SessionDep) -> Response:
    robot = load_robot(session, robot_id)
    if robot.preset:
        raise ConflictError(f"robot {robot_id!r} is a preset and cannot be deleted")
    session.delete(robot)
    session.commit()
    return Response(status_code=status.HTTP_204_NO_CONTENT)


#: Engine state fields and their names in the request body.
STATE_FIELDS = {"q": "joint_angles_deg", "base_position": "base_position_m", "base_attitude": "base_attitude_quaternion"}


@router.post(
    "/{robot_id}/jacobian",
    operation_id="compute_jacobian",
    response_model=JacobianOut,
    summary="Generalized Jacobian (GJM) and end-effector pose at a state",
    responses=responses(404, 422),
)
def compute_jacobian(robot_id: str, body: JacobianRequest, session: SessionDep) -> JacobianOut:
    model = robot_model(load_robot(session, robot_id).parameters)
    try:
        attitude = quaternion_to_matrix(body.base_attitude_quaternion) if body.base_attitude_quaternion else np.eye(3)
    except ValueError as exc:
        loc = ["body", "base_attitude_quaternion"]
        raise ApiValidationError(f"base_attitude_quaternion: {exc}", [{"loc": loc, "msg": str(exc)}]) from None
    try:
        state = State(
            np.radians(body.joint_angles_deg),
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
