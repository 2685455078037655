"""Robots: stored parameter sets (given as such, or derived from a URDF), their URDF, and the
generalized Jacobian at a state. A URDF upload is read behind the plan admission, like a plan
(reading one costs up to a few hundred milliseconds of CPU)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Body, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError

from service.deps import DbDep, JsonBody, Limit, Offset, RobotId, SessionDep, SessionRoute, SettingsDep, one_of_body, run_admitted
from service.errors import ApiValidationError, body_invalid, responses
from service.schemas.robots import JacobianOut, JacobianRequest, RobotList, RobotOut, RobotParams, RobotUrdfIn
from service.usecases import robots

router = APIRouter(prefix="/v1/robots", tags=["robots"], route_class=SessionRoute)


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
    return robots.listing(session, limit, offset)


CREATE_ROBOT_BODY = one_of_body(
    (RobotParams, RobotUrdfIn),
    {
        "urdf": {
            "summary": "a URDF robot (the URDF as text in the `urdf` field)",
            "value": {"urdf": "<robot name='my-arm'>...</robot>", "end_effector_link": "tool0"},
        }
    },
)


def _validated(body: dict[str, Any]) -> RobotParams | RobotUrdfIn:
    """``body`` validated as the schema it is (URDF or parameters), errors under ``body`` like FastAPI's own."""
    if isinstance(body.get("parameters"), dict) and not {"base", "links", "urdf"} & body.keys():
        # a stored robot's answer posted back: one error that says what to post, not one per field
        raise ApiValidationError.at(
            ["body"],
            "a robot's `parameters` are the parameter set itself, not a field of it (GET /v1/robots/{robot_id} answers "
            "with them beside id, joints, ...): to store a copy, post the `parameters` object (with a `name` of its own)",
        )
    try:
        return robots.parameters_of(body).model_validate(body)
    except ValidationError as exc:
        raise body_invalid(exc) from None


@router.post(
    "",
    operation_id="create_robot",
    response_model=RobotOut,
    status_code=status.HTTP_201_CREATED,
    summary="Store a robot: a parameter set (schema of engine/data/table1_robot.json, SI units) or a URDF (JSON field `urdf`)",
    description="The body is either a parameter set (`RobotParams`) or a URDF document as text in the field `urdf`, "
    "with `end_effector_link` and an optional tool offset (`RobotUrdfIn`). A URDF robot is stored as the parameter set "
    "derived from it (shown in the response); a URDF the service cannot use is a 422 whose `element` names the URDF "
    "element at fault. The parameters are checked as the engine needs them (masses positive, inertias symmetric "
    "positive definite and physical, joint axes and rotations valid; a 422 names the field, e.g. "
    "`body.links[2].inertia`) and the joint axes normalised; 201 with the robot and its `Location`. The bounds and "
    "messages are the same for a URDF's derived parameters (a 422 at `body.urdf` naming the link). A URDF is read "
    "behind the plan admission (503 with `Retry-After` when it is full).",
    responses=responses(415, 422),
    dependencies=[JsonBody],
    openapi_extra=CREATE_ROBOT_BODY,
)
async def create_robot(request: Request, settings: SettingsDep, response: Response, body: dict[str, Any] = Body(...)) -> RobotOut:
    validated = _validated(body)

    def work() -> RobotOut:
        with request.app.state.db.session() as session:
            return robots.create(session, settings.storage_quota_bytes, validated)

    if isinstance(validated, RobotUrdfIn):
        created = await run_admitted(request, work, "plans and URDF uploads")
    else:
        created = await run_in_threadpool(work)
    response.headers["Location"] = f"/v1/robots/{created.id}"
    return created


@router.get(
    "/{robot_id}",
    operation_id="get_robot",
    response_model=RobotOut,
    summary="Get a robot",
    description="A stored robot and its parameter set; `table1` is the paper's Table-1 robot. A robot stored by an "
    "older version with parameters this one refuses is a 409 that says why (delete it and store it again).",
    responses=responses(404, 409),
)
def get_robot(robot_id: RobotId, session: SessionDep) -> RobotOut:
    return robots.view(robots.load(session, robot_id))


@router.get(
    "/{robot_id}/urdf",
    operation_id="get_robot_urdf",
    summary="The robot as a URDF document (reads back to the same model here and in Pinocchio)",
    description="The stored robot as URDF text (SI units; revolute, continuous and prismatic joints with their "
    "limits; each body's collision shapes as `<collision>` elements of standard URDF, a capsule as a cylinder with a "
    "sphere on each end, which reading merges back into the capsule): `POST /v1/robots` with it in `urdf` (and its "
    "end-effector link) stores the same model again. A convex (mesh) collision shape is not written, since URDF "
    "carries meshes as files only; a comment in its link says so.",
    response_class=Response,
    responses={
        200: {"description": "URDF (XML)", "content": {"application/xml": {"schema": {"type": "string"}}}},
        **responses(404, 409),
    },
)
def get_robot_urdf(robot_id: RobotId, session: SessionDep) -> Response:
    return Response(robots.urdf(session, robot_id), media_type="application/xml")


@router.delete(
    "/{robot_id}",
    operation_id="delete_robot",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a robot (presets cannot be deleted)",
    description="204 once deleted. Stored plans keep their results (their `robot_id` becomes null); a queued tuning job "
    "for the robot fails when a worker takes it. Deleting a preset is a 409.",
    responses=responses(404, 409),
)
def delete_robot(robot_id: RobotId, db: DbDep) -> Response:
    robots.delete(db, robot_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post(
    "/{robot_id}/jacobian",
    operation_id="compute_jacobian",
    response_model=JacobianOut,
    summary="Generalized Jacobian (GJM) and end-effector pose at a state",
    description="The GJM of the free-floating robot (the base's reaction included, zero momentum) at the joint angles "
    "and base pose given, with its singular values, determinant, manipulability and condition number, and the "
    "end-effector pose. Nothing is stored. The state may lie outside the joints' limits (the GJM is defined there too; "
    "a plan's start may not). A GJM that is not finite at that state (masses too small for double precision) is a 422 "
    "that says so.",
    responses=responses(404, 409, 415, 422),
    dependencies=[JsonBody],
)
def compute_jacobian(robot_id: RobotId, body: JacobianRequest, session: SessionDep) -> JacobianOut:
    return robots.jacobian(session, robot_id, body)
