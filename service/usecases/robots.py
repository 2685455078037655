"""Robots: the robot a request names (stored or inline), stored robots and their views, the
presets every database starts with, and the GJM at a state.

Every robot goes through one validation, whatever its source (:func:`service.schemas.robots.model_of`):
a new one's response is built from the row about to be stored, before the transaction commits,
so nothing is stored that cannot be served. A row stored by an older version that this one
cannot use is isolated: its own requests answer a 409 that says why (a request naming it as
``robot_id``, a 422), and lists leave it out."""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from engine import RobotModel, generalized_jacobian
from engine.errors import ParameterError
from service.errors import ApiError, ApiValidationError, ConflictError
from service.infra import jsonio
from service.infra.db import Database
from service.infra.lru import Lru
from service.infra.quota import check_quota
from service.infra.revision import missing_presets
from service.models import Robot, new_id, utcnow
from service.schemas.common import located
from service.schemas.robots import (
    JacobianOut,
    JacobianRequest,
    RobotList,
    RobotOut,
    RobotParams,
    RobotUrdfIn,
    distinct_names,
    model_of,
)
from service.usecases import meshes, rows

PRESET_ROBOT_ID = "table1"
log = logging.getLogger("spacearm.api")


class UnusableRobotError(ConflictError):
    """A stored robot whose parameters do not pass the validation of robots (stored by an older
    version): a 409 of its own, never a failing list."""

    def __init__(self, robot_id: str, reason: str) -> None:
        super().__init__(
            f"robot {robot_id!r} is stored with parameters this service cannot use ({reason}): delete it and store it again"
        )


def preset_robots() -> dict[str, Callable[[], RobotModel]]:
    """The robots every database starts with: the paper's Table-1 robot, the same with collision
    geometry (``table1-geometry``: capsule links and a carrier cube) and the URDF examples (a
    7-joint arm on a spacecraft, a 3-joint arm), each built only when missing (reading a URDF
    imports its parser, about a second)."""
    from engine import table1_robot, urdf_robot
    from engine.model import URDF_PRESETS, table1_with_geometry

    return {
        PRESET_ROBOT_ID: table1_robot,
        "table1-geometry": table1_with_geometry,
        **{name: functools.partial(urdf_robot, name) for name in URDF_PRESETS},
    }


def seed_presets(db: Database) -> None:
    """Insert the preset robots that are missing (idempotent), building only those: the URDF
    presets import the URDF parser, and trimesh with it, about 60 MiB of RSS that stays in the
    process (``spacearm run`` has its short-lived migration seed them)."""
    builders = preset_robots()
    for robot_id in missing_presets(db.engine):
        model = builders[robot_id]()
        try:
            with db.session() as session:
                session.add(Robot(id=robot_id, name=model.name, parameters=model.to_dict(), preset=True))
        except IntegrityError:  # another process seeded it at the same time
            pass


#: Stored robots' models by id, read by plan requests (:func:`kept`). A stored robot never changes:
#: robots are created and deleted, never updated, and ids are not reused. A robot deleted since
#: (by another API process too) fails the plan's insert on the plans' foreign key, which
#: :func:`service.usecases.plans.store` answers with this 404.
_STORED: Lru[str, RobotModel] = Lru(256)


def kept(robot_id: str) -> RobotModel | None:
    """The model of stored robot ``robot_id`` as a request of this process last read it, or None."""
    return _STORED.peek(robot_id)


def forget(robot_id: str) -> None:
    """Stop keeping stored robot ``robot_id`` (deleted)."""
    _STORED.discard(robot_id)


def load(session: Session, robot_id: str) -> Robot:
    return rows.load(session, Robot, robot_id, "robot")


def resolve(
    session: Session, robot_id: str | None, inline: RobotParams | None, *, new: bool = True
) -> tuple[str | None, RobotModel]:
    """The robot of a request: its inline parameters (errors at ``body.robot...``; ``new``: a
    request's, whose names must be distinct, not a queued job's) or the stored robot ``robot_id``."""
    if inline is not None:
        with located(inline, "body", "robot"):
            model = inline.to_engine()
            if new:
                distinct_names(model, inline)
            return None, model
    if robot_id is None:
        raise ApiValidationError.at(
            ["body", "robot_id"],
            "robot_id or robot is required",
            detail="give either robot_id (a stored robot, e.g. 'table1') or an inline robot",
        )
    try:
        model = stored_model(load(session, robot_id))
        _STORED.put(robot_id, model)
        return robot_id, model
    except UnusableRobotError as exc:
        raise ApiValidationError.at(["body", "robot_id"], exc.detail) from None


def stored_model(robot: Robot) -> RobotModel:
    """The model of a stored robot, or its own 409 (:class:`UnusableRobotError`)."""
    try:
        return model_of(robot.parameters)
    except ParameterError as exc:
        raise UnusableRobotError(robot.id, f"{exc.field}: {exc.reason}") from None


def resolve_preset(robot_id: str | None, inline: RobotParams | None) -> tuple[str | None, RobotModel]:
    """As :func:`resolve` without a database (``spacearm plan``): the inline robot, or a preset."""
    if inline is not None or robot_id is None:
        return resolve(None, robot_id, inline)  # type: ignore[arg-type]  # no session needed
    build = preset_robots().get(robot_id)
    if build is None:
        presets = ", ".join(preset_robots())
        raise ApiError(404, f"robot {robot_id!r} is not a preset ({presets}): without a server, give a preset or an inline robot")
    return robot_id, build()


def view(robot: Robot) -> RobotOut:
    return RobotOut.from_engine(robot.id, robot.name, robot.preset, robot.parameters, robot.created_at, stored_model(robot))


def listing(session: Session, limit: int, offset: int) -> RobotList:
    """A page of robots; a row that cannot be shown is left out (and logged), the others are listed."""
    total = session.scalar(select(func.count()).select_from(Robot)) or 0
    rows = session.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(limit).offset(offset)).all()
    items = []
    for row in rows:
        try:
            items.append(view(row))
        except UnusableRobotError as exc:
            log.warning("left out of the robot list: %s", exc.detail)
    return RobotList(items=items, total=total)


def create(session: Session, quota_bytes: int | None, body: RobotParams | RobotUrdfIn) -> RobotOut:
    """Store a robot given by parameters or by URDF (stored as the parameter set derived from it).
    The answer is built (and so checked) from the row before it is committed: a robot that could
    not be shown is never stored."""
    with located(body, "body"), meshes.hulls(session):  # a URDF may name stored meshes
        model = body.to_engine()
        if isinstance(body, RobotParams):
            distinct_names(model, body)
    parameters = jsonio.clean(model.to_dict())
    check_quota(session, quota_bytes, len(jsonio.dumps(parameters)))
    robot = Robot(id=new_id(), name=model.name, parameters=parameters, preset=False, created_at=utcnow())
    created = view(robot)
    session.add(robot)
    session.commit()  # before the response goes out: a client's next request must see it
    return created


def delete(db: Database, robot_id: str) -> None:
    """Delete a robot (presets cannot be; also on a full disk: :meth:`Database.freeing`)."""

    def remove(session: Session) -> None:
        robot = load(session, robot_id)
        if robot.preset:
            raise ConflictError(f"robot {robot_id!r} is a preset and cannot be deleted")
        session.delete(robot)

    db.freeing(lambda: db.write(remove))
    forget(robot_id)


def urdf(session: Session, robot_id: str) -> str:
    return stored_model(load(session, robot_id)).to_urdf()


def jacobian(session: Session, robot_id: str, body: JacobianRequest) -> JacobianOut:
    """The GJM at a state; a GJM that is not finite (masses too small for double precision) is a
    422 with the engine's message."""
    model = stored_model(load(session, robot_id))
    with located(body, "body"):
        gjm = generalized_jacobian(model, body.to_engine(model))
    if not gjm.success:
        raise ApiValidationError.at(["path", "robot_id"], gjm.message, detail=f"robot {robot_id!r}: {gjm.message}")
    return JacobianOut.from_engine(gjm)


def parameters_of(body: dict[str, Any]) -> type[RobotParams] | type[RobotUrdfIn]:
    """Which schema a robot body is: a URDF (it has ``urdf``) or a parameter set."""
    return RobotUrdfIn if "urdf" in body else RobotParams
