"""Synchronous plans (:mod:`service.usecases.plans`). A plan request waits for a slot of the plan admission
(:mod:`service.infra.admission`: a few plans at once, a short queue, then 503 with ``Retry-After``) on
the event loop, then runs in the thread pool (the engine's kernels release the GIL, so plans run
in parallel on every core). Reads are plain ``def`` handlers in the thread pool.

Plan bodies are written once, by orjson from the planner's arrays (:mod:`service.infra.jsonio`): the
trajectory is neither copied into Python lists nor validated again on the way out. Trajectories
are stored as compressed arrays (:mod:`service.infra.storage`). ``fields`` leaves out the large
sections."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response, status

from service.deps import FieldsQuery, Limit, Offset, PlanId, SessionDep, SessionRoute, SettingsDep, run_admitted
from service.errors import responses
from service.infra.db import Database
from service.schemas.plans import PlanList, PlanOut, PlanRequest
from service.usecases import plans

router = APIRouter(prefix="/v1/plans", tags=["plans"], route_class=SessionRoute)


@router.post(
    "",
    operation_id="create_plan",
    response_model=PlanOut,
    status_code=status.HTTP_201_CREATED,
    summary="Plan a Cartesian task (synchronous) and store the plan",
    description="Plans the task with the robust inverse given (the base moving freely, momentum conserved), replays "
    "it independently if `replay` is true, stores it and answers 201 with the plan and its `Location`. A plan that "
    "fails (diverges, breaks the joint speed limit, leaves the path) is still a result: `success` is false and "
    "`message` says where and why. Plans run a few at a time per API process; beyond a short queue the answer is "
    "503 with `Retry-After`. `fields` chooses the sections of the answer.",
    responses=responses(404, 422),
)
async def create_plan(body: PlanRequest, request: Request, settings: SettingsDep, fields: FieldsQuery = None) -> Response:
    sections = plans.parse_sections(fields)
    db: Database = request.app.state.db

    def work() -> Response:
        row = plans.store(db, settings, planned := plans.compute(db, settings, body))
        content = plans.body_json(plans.summary(row), sections, planned.record, row.replay)
        return Response(content, status_code=201, media_type="application/json", headers={"Location": f"/v1/plans/{row.id}"})

    return await run_admitted(request, work)


@router.get(
    "",
    operation_id="list_plans",
    response_model=PlanList,
    summary="List stored plans (without trajectories)",
    description="Stored plans, newest first, `limit` at a time from `offset`: each plan's summary (method, verdict, "
    "metrics); `total` counts them all.",
)
def list_plans(session: SessionDep, limit: Limit = 50, offset: Offset = 0) -> PlanList:
    return plans.listing(session, limit, offset)


@router.get(
    "/{plan_id:id}",
    operation_id="get_plan",
    response_model=PlanOut,
    summary="Get a stored plan",
    description="A stored plan as `POST /v1/plans` answered it; `fields` chooses the sections (`fields=` for the "
    "summary only, `fields=replay` without the trajectory).",
    responses=responses(404, 422),
)
def get_plan(plan_id: PlanId, session: SessionDep, fields: FieldsQuery = None) -> Response:
    return Response(plans.read(session, plan_id, plans.parse_sections(fields)), media_type="application/json")


@router.delete(
    "/{plan_id:id}",
    operation_id="delete_plan",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a stored plan",
    description="204 once deleted; 404 for an unknown id. Its figures are no longer served.",
    responses=responses(404),
)
def delete_plan(plan_id: PlanId, session: SessionDep) -> Response:
    plans.delete(session, plan_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
