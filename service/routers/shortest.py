"""The shortest feasible duration of a task's path for a method (synchronous): the engine's
bisection (:func:`engine.shortest_duration`, :func:`service.usecases.plans.compute_shortest`),
then the plan at the duration found, stored like any plan (its request carries that duration, so
posting it to ``/v1/plans`` plans it again)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response, status

from service.deps import FieldsQuery, JsonAnswer, JsonBody, SessionRoute, SettingsDep, run_admitted
from service.errors import responses
from service.infra import jsonio
from service.infra.db import Database
from service.schemas.plans import ShortestDurationOut, ShortestDurationRequest
from service.usecases import plans

router = APIRouter(prefix="/v1/plans", tags=["plans"], route_class=SessionRoute)


@router.post(
    "/shortest-duration",
    operation_id="create_shortest_duration_plan",
    response_model=ShortestDurationOut,
    status_code=status.HTTP_201_CREATED,
    summary="Find the shortest feasible duration of a task for a method, and store the plan at it",
    description="Bisection on the duration of the task's path (retimed uniformly: same geometry, every speed "
    "scaled), several candidate durations planned per round in parallel, until the shortest feasible duration "
    "found is within `search.relative_tolerance` of the longest infeasible one below it. Feasible = the plan "
    "succeeds: finite, within the joint speed limit, on the path and at the target within the tolerances. "
    "Answers 201 with the search and the stored plan at the duration found (`Location` names it); when no "
    "duration up to the maximum is feasible, `search.success` is false and the plan is the one at the longest "
    "duration tried. `fields` as for `POST /v1/plans`.",
    responses=responses(404, 406, 415, 422),
    dependencies=[JsonAnswer, JsonBody],
)
async def create_shortest_duration_plan(
    body: ShortestDurationRequest, request: Request, settings: SettingsDep, fields: FieldsQuery = None
) -> Response:
    sections = plans.parse_sections(fields)
    db: Database = request.app.state.db

    def work() -> Response:
        planned, search = plans.compute_shortest(db, settings, body)
        row = plans.store(db, settings, planned)
        plan = plans.body_json(plans.summary(row), sections, planned.record, row.replay)
        content = b'{"search":' + jsonio.dumps(search.model_dump(mode="json")) + b',"plan":' + plan + b"}"
        return Response(content, status_code=201, media_type="application/json", headers={"Location": f"/v1/plans/{row.id}"})

    return await run_admitted(request, work)
