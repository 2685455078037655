"""Robots: the robot a request names (stored or inline), stored robots and their views, the
presets every database starts with, and the GJM at a state."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from engine import RobotModel, generalized_jacobian
from service.errors import ApiValidationError, ConflictError
from service.infra import jsonio
from service.infra.db import Database
from service.infra.quota import check_quota
from service.models import Robot
from service.schemas.common import located
from service.schemas.robots import JacobianOut, JacobianRequest, RobotList, RobotOut, RobotParams, RobotUrdfIn, model_of
from service.usecases import rows

PRESET_ROBOT_ID = "table1"


def preset_robots() -> dict[str, Callable[[], RobotModel]]:
    """The robots every database starts with: the paper's Table-1 robot and the URDF examples (a
    7-joint arm on a spacecraft, a 3-joint arm), each built only when missing (reading a URDF
    imports its parser, about a second)."""
    from engine import table1_robot, urdf_robot
    from engine.model import URDF_PRESETS

    return {PRESET_ROBOT_ID: table1_robot, **{name: functools.partial(urdf_robot, name) for name in URDF_PRESETS}}


def seed_presets(db: Database) -> None:
    """Insert the preset robots that are missing (idempotent)."""
    for robot_id, build in preset_robots().items():
        try:
            with db.session() as session:
                if session.scalar(select(Robot.id).where(Robot.id == robot_id)) is None:
                    model = build()
                    session.add(Robot(id=robot_id, name=model.name, parameters=model.to_dict(), preset=True))
        except IntegrityError:  # another process seeded it at the same time
            pass


def load(session: Session, robot_id: str) -> Robot:
    return rows.load(session, Robot, robot_id, "robot")


def resolve(session: Session, robot_id: str | None, inline: RobotParams | None) -> tuple[str | None, RobotModel]:
    """The robot of a request: its inline parameters (errors at ``body.robot...``) or the stored
    robot ``robot_id``."""
    if inline is not None:
        with located(inline, "body", "robot"):
            return None, inline.to_engine()
    if robot_id is None:
        raise ApiValidationError(
            "give either robot_id (a stored robot, e.g. 'table1') or an inline robot",
            [{"loc": ["body", "robot_id"], "msg": "robot_id or robot is required"}],
        )
    return robot_id, model_of(load(session, robot_id).parameters)


def view(robot: Robot) -> RobotOut:
    return RobotOut.from_engine(
        robot.id, robot.name, robot.preset, robot.parameters, robot.created_at, model_of(robot.parameters)
    )


def listing(session: Session, limit: int, offset: int) -> RobotList:
    total = session.scalar(select(func.count()).select_from(Robot)) or 0
    rows = session.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(limit).offset(offset)).all()
    return RobotList(items=[view(r) for r in rows], total=total)


def create(session: Session, quota_bytes: int | None, body: RobotParams | RobotUrdfIn) -> RobotOut:
    """Store a robot given by parameters or by URDF (stored as the parameter set derived from it)."""
    with located(body, "body"):
        model = body.to_engine()
    parameters = jsonio.clean(model.to_dict())
    check_quota(session, quota_bytes, len(jsonio.dumps(parameters)))
    robot = Robot(name=model.name, parameters=parameters, preset=False)
    session.add(robot)
    session.commit()  # before the response goes out: a client's next request must see it
    return view(robot)


def delete(session: Session, robot_id: str) -> None:
    robot = load(session, robot_id)
    if robot.preset:
        raise ConflictError(f"robot {robot_id!r} is a preset and cannot be deleted")
    session.delete(robot)
    session.commit()


def urdf(session: Session, robot_id: str) -> str:
    return model_of(load(session, robot_id).parameters).to_urdf()


def jacobian(session: Session, robot_id: str, body: JacobianRequest) -> JacobianOut:
    model = model_of(load(session, robot_id).parameters)
    with located(body, "body"):
        return JacobianOut.from_engine(generalized_jacobian(model, body.to_engine(model)))


def parameters_of(body: dict[str, Any]) -> type[RobotParams] | type[RobotUrdfIn]:
    """Which schema a robot body is: a URDF (it has ``urdf``) or a parameter set."""
    return RobotUrdfIn if "urdf" in body else RobotParams
