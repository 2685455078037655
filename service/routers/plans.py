"""Synchronous plans (:mod:`service.usecases.plans`). A plan request waits for a slot of the plan admission
(:mod:`service.infra.admission`: a few plans at once, a short queue, then 503 with ``Retry-After``) on
the event loop, then runs there if it is cheap (a paper plan: the hand-off to a thread cost more
than a third of the request; the rest goes to a thread if the prepared task is larger than the
body said, or if another writer holds the database), else in the thread pool (the engine's kernels
release the GIL, so plans run in parallel on every core). A plan is read where cheap plans run (on
the loop, unless its stored request and trajectory are large:
:data:`~service.infra.admission.INLINE_READ_BYTES`); the other reads are plain ``def`` handlers in
the thread pool.

Plan bodies are written once, by orjson from the planner's arrays (:mod:`service.infra.jsonio`): the
trajectory is neither copied into Python lists nor validated again on the way out. Trajectories
are stored as compressed arrays (:mod:`service.infra.storage`). ``fields`` leaves out the large
sections."""

from __future__ import annotations

import math
from typing import Annotated, Any

from fastapi import APIRouter, Body, Query, Request, Response, status

from service.deps import (
    DbDep,
    FieldsQuery,
    JsonBody,
    JsonOnly,
    Limit,
    Offset,
    PlanId,
    SessionDep,
    SessionRoute,
    SettingsDep,
    negotiate,
    one_of_body,
    run_admitted,
    run_read,
    schema_ref,
)
from service.errors import NotAcceptableError, responses
from service.infra.admission import INLINE_READ_BYTES, plan_cost
from service.infra.db import Database, elsewhere_if_locked
from service.infra.loop import HandOff, on_event_loop
from service.schemas.methods import MethodName
from service.schemas.plans import PathTypeName, PlanList, PlanOut, PlanRequest, PlanRerun, Trajectory
from service.schemas.trajectories import MEDIA_TYPES, RosJointTrajectory, TrajectoryFormat
from service.usecases import plans, trajectories

router = APIRouter(prefix="/v1/plans", tags=["plans"], route_class=SessionRoute)


CREATE_PLAN_BODY = one_of_body(
    (PlanRequest, PlanRerun),
    {
        "plan": {"summary": "a plan request", "value": PlanRequest.model_config["json_schema_extra"]["examples"][0]},  # type: ignore[index]
        "rerun": {
            "summary": "a stored plan again, with changes (a JSON merge patch of its request)",
            "value": PlanRerun.model_config["json_schema_extra"]["examples"][0],  # type: ignore[index]
        },
    },
)


@router.post(
    "",
    operation_id="create_plan",
    response_model=PlanOut,
    status_code=status.HTTP_201_CREATED,
    summary="Plan a Cartesian task (synchronous) and store the plan",
    description="Plans the task with the robust inverse given (the base moving freely, momentum conserved), replays "
    "it independently if `replay` is true, stores it and answers 201 with the plan and its `Location`. A plan that "
    "fails (diverges, breaks the joint speed limit, leaves the path) is still a result: `success` is false and "
    "`message` says where and why. The body is a plan request (`PlanRequest`), or a stored plan's id as "
    "`from_plan_id` with changes (`PlanRerun`: merged into that plan's stored request as a JSON merge patch, RFC "
    "7396, a changed path `type` or method `name` replacing the object whole). "
    "Plans run a few at a time per API process and wait their turn; a request whose estimated wait (the work "
    "admitted before it, in joint-steps, at the measured speed) exceeds `SPACEARM_PLAN_QUEUE_TIMEOUT_S` is a 503 "
    "with `Retry-After`. `fields` chooses the sections of the answer. The answer is JSON: an `Accept` without "
    "it is a 406 (the trajectory in other formats: `GET /v1/plans/{plan_id}/trajectory`).",
    responses=responses(404, 406, 415, 422),
    dependencies=[JsonOnly, JsonBody],
    openapi_extra=CREATE_PLAN_BODY,
)
async def create_plan(
    request: Request, settings: SettingsDep, body: dict[str, Any] = Body(...), fields: FieldsQuery = None
) -> Response:
    sections = plans.parse_sections(fields)
    db: Database = request.app.state.db

    def answer(asked: PlanRequest, planned: plans.Planned) -> Response:
        row = plans.store(db, settings, planned)
        content = plans.body_json(plans.summary(row, asked), sections, planned.record, row.replay)
        return Response(content, status_code=201, media_type="application/json", headers={"Location": f"/v1/plans/{row.id}"})

    def work() -> Response:
        asked = plans.request_of(db, body)
        # on the event loop, a task larger than its request said is planned in a thread
        within = request.app.state.plan_admission.inline_max_cost if on_event_loop() else math.inf
        try:
            planned = plans.compute(db, settings, asked, within=within)
        except HandOff as larger:
            plan = larger.then  # the name `larger` is gone after the except clause
            raise HandOff(lambda: answer(asked, plan())) from None
        with elsewhere_if_locked(lambda: answer(asked, planned)):  # matters on the event loop only
            return answer(asked, planned)

    return await run_admitted(request, work, cost=plan_cost(body))


@router.get(
    "",
    operation_id="list_plans",
    response_model=PlanList,
    summary="List stored plans (without trajectories)",
    description="Stored plans, newest first, `limit` at a time from `offset`: each plan's summary (its request, "
    "method, verdict, metrics); `total` counts those the filters keep. Filters (all optional, combined with and): "
    "`robot_id`, `path_type` (the task's path; plans stored before paths existed are lines), `method` (the inverse's "
    "name), `success`.",
    responses=responses(422),
)
def list_plans(
    session: SessionDep,
    limit: Limit = 50,
    offset: Offset = 0,
    robot_id: Annotated[str | None, Query(max_length=64, description="only plans for this stored robot")] = None,
    path_type: Annotated[PathTypeName | None, Query(description="only plans whose task follows this path type")] = None,
    method: Annotated[MethodName | None, Query(description="only plans with this inverse method")] = None,
    success: Annotated[bool | None, Query(description="only successful (true) or failed (false) plans")] = None,
) -> PlanList:
    return plans.listing(session, limit, offset, plans.PlanFilter(robot_id, path_type, method, success))


@router.get(
    "/{plan_id:id}",
    operation_id="get_plan",
    response_model=PlanOut,
    summary="Get a stored plan",
    description="A stored plan as `POST /v1/plans` answered it; `fields` chooses the sections (`fields=` for the "
    "summary only, `fields=replay` without the trajectory). The answer is JSON: an `Accept` without it (`text/csv`, "
    "say) is a 406 that points to `GET /v1/plans/{plan_id}/trajectory`, which exports CSV, MAT, NPZ and ROS.",
    responses=responses(404, 406, 422),
    dependencies=[JsonOnly],
)
async def get_plan(request: Request, plan_id: PlanId, fields: FieldsQuery = None) -> Response:
    sections = plans.parse_sections(fields)
    db: Database = request.app.state.db

    def work() -> bytes:
        # on the event loop, a large plan (request and trajectory) is read in a thread
        return plans.read(db, plan_id, sections, within=INLINE_READ_BYTES if on_event_loop() else math.inf)

    return Response(await run_read(request, work), media_type="application/json")


TRAJECTORY_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "the trajectory in the format asked for",
        # A binary type first: generators that read one media type per response (openapi-python-client
        # takes the first) then answer every format as bytes, instead of failing to parse CSV as JSON.
        "content": {
            MEDIA_TYPES["mat"]: {"schema": {"type": "string", "format": "binary"}},
            MEDIA_TYPES["npz"]: {"schema": {"type": "string", "format": "binary"}},
            MEDIA_TYPES["json"]: {"schema": schema_ref(Trajectory)},
            MEDIA_TYPES["csv"]: {"schema": {"type": "string"}},
            # RosJointTrajectory is added to the document's components by service.openapi (BODY_MODELS)
            MEDIA_TYPES["ros"]: {"schema": schema_ref(RosJointTrajectory)},
        },
        "headers": {
            "Content-Disposition": {
                "description": '`attachment; filename="plan-<id>.<ext>"`',
                "schema": {"type": "string"},
            }
        },
    },
    **responses(404, 406, 409),
}


@router.get(
    "/{plan_id:id}/trajectory",
    operation_id="get_plan_trajectory",
    summary="Export a stored plan's trajectory: JSON, CSV, MATLAB/Octave .mat, numpy .npz or a ROS 2 JointTrajectory",
    description="`format` chooses the format; without it, `Accept` does: "
    + ", ".join(f"`{fmt}` {media}" for fmt, media in MEDIA_TYPES.items())
    + " (no `Accept`, or `*/*`: JSON). An `Accept` that names none of them, without `format`, is a 406 whose "
    "`available` lists them. `json` is the plan's `trajectory` section; `csv` has one header row (each column one "
    "component of one of those arrays, its name carrying its unit: `t_s`, `joint_angles_deg[joint1]`, "
    "`base_position_m[x]`, `ee_attitude_quaternion[w]`, ...) and one row per sample, empty where a value is not "
    "finite; `mat` (MATLAB 5, `load` in MATLAB or Octave) and `npz` hold the same arrays under the same names, plus "
    "`joint_names`; `ros` is a `trajectory_msgs/JointTrajectory` as JSON (SI units: rad, m, rad/s, m/s; "
    "`time_from_start` as `sec`/`nanosec`); a plan that diverged has none (409).",
    response_class=Response,
    responses=TRAJECTORY_RESPONSES,
)
def get_plan_trajectory(
    plan_id: PlanId,
    request: Request,
    session: SessionDep,
    format: Annotated[
        TrajectoryFormat | None, Query(description="the format (wins over `Accept`): json, csv, mat, npz or ros")
    ] = None,
) -> Response:
    if format is None:
        media = negotiate(request.headers.get("accept"), list(MEDIA_TYPES.values()))
        if media is None:
            raise NotAcceptableError(
                f"{request.headers.get('accept')!r} not available: the trajectory is "
                + ", ".join(f"{media} (format={fmt})" for fmt, media in MEDIA_TYPES.items()),
                list(MEDIA_TYPES.values()),
            )
        format = next(fmt for fmt, m in MEDIA_TYPES.items() if m == media)  # type: ignore[misc]
    out = trajectories.export(session, plan_id, str(format))
    headers = {"Content-Disposition": f'attachment; filename="{out.filename}"', "Vary": "Accept"}
    return Response(out.content, media_type=out.media_type, headers=headers)


@router.delete(
    "/{plan_id:id}",
    operation_id="delete_plan",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a stored plan",
    description="204 once deleted; 404 for an unknown id. Its figures are no longer served.",
    responses=responses(404),
)
def delete_plan(plan_id: PlanId, db: DbDep) -> Response:
    plans.delete(db, plan_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
