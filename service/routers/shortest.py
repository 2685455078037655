"""The shortest feasible duration of a task's path for a method (synchronous): the engine's
bisection (:func:`engine.shortest_duration`), then the plan at the duration found, stored like
any plan (its request carries that duration, so posting it to ``/v1/plans`` plans it again)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from fastapi import APIRouter, Request, Response, status
from sqlalchemy.orm import Session

from engine import DurationSearch, PlanResult, RobotModel, shortest_duration
from engine.errors import ParameterError
from engine.paths import ArcPath
from service.convert import build_task, clean, resolve_robot
from service.deps import SessionRoute, SettingsDep
from service.errors import ApiValidationError, responses
from service.infra import jsonio
from service.infra.db import Database
from service.infra.settings import Settings
from service.models import Plan
from service.routers.plans import FieldsQuery, check_method, finish_plan, parse_fields, plan_options, run_admitted, store_plan
from service.schemas.plans import PlanRequest, ShortestDurationOut, ShortestDurationRequest

router = APIRouter(prefix="/v1/plans", tags=["plans"], route_class=SessionRoute)


def search_out(found: DurationSearch) -> dict[str, Any]:
    return clean(
        {
            "success": found.success,
            "message": found.message,
            "duration_s": found.duration,
            "infeasible_duration_s": found.infeasible_duration,
            "relative_gap": found.relative_gap,
            "joint_speed_margin_deg_s": math.degrees(found.speed_margin),
            "limiting": found.limiting,
            "evaluations": found.evaluations,
            "rounds": found.rounds,
        }
    )


def planned_request(body: ShortestDurationRequest, result: PlanResult) -> PlanRequest:
    """The plan request of the duration found: the task's duration and (for lines and arcs,
    whose ramp scales with it) ramp time are those of the plan."""
    task = result.task
    ramp = task.followed.ramp_time if isinstance(task.followed, ArcPath) else task.ramp_time
    fields = {"duration_s": task.duration}
    if body.task.path.type in ("line", "arc"):
        fields["ramp_time_s"] = ramp
    stored = body.stored()
    del stored["search"]
    stored["task"] = {**stored["task"], **fields}
    return PlanRequest.model_validate_json(jsonio.dumps(stored))


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
    responses=responses(404, 422),
)
async def create_shortest_duration_plan(
    body: ShortestDurationRequest, request: Request, settings: SettingsDep, fields: FieldsQuery = None
) -> Response:
    sections = parse_fields(fields)
    found: list[DurationSearch] = []

    def compute(session: Session) -> tuple[Plan, dict[str, np.ndarray]]:
        robot_id, model = resolve_robot(session, body.robot_id, body.robot)
        session.rollback()  # no connection held during the search
        row, trajectory, search = _search(body, robot_id, model, settings)
        found.append(search)
        return row, trajectory

    def wrap(plan: bytes) -> bytes:
        return b'{"search":' + jsonio.dumps(search_out(found[0])) + b',"plan":' + plan + b"}"

    db: Database = request.app.state.db
    return await run_admitted(request, store_plan, db, settings, sections, compute, wrap)


def _search(
    body: ShortestDurationRequest, robot_id: str | None, model: RobotModel, settings: Settings
) -> tuple[Plan, dict[str, np.ndarray], DurationSearch]:
    task = build_task(model, body.task)
    inverse = check_method(body.method.name, body.method.params.given())
    found: list[DurationSearch] = []

    def search() -> PlanResult:
        try:
            found.append(
                shortest_duration(
                    model,
                    task,
                    inverse,
                    **plan_options(body),
                    relative_tolerance=body.search.relative_tolerance,
                    candidates=body.search.candidates,
                    max_duration=body.search.max_duration_s,
                )
            )
        except ParameterError as exc:
            if exc.field != "max_duration":
                raise
            loc = ["body", "search", "max_duration_s"]
            raise ApiValidationError(f"search.max_duration_s: {exc.reason}", [{"loc": loc, "msg": exc.reason}]) from None
        return found[0].plan

    row, trajectory = finish_plan(body, robot_id, model, settings, search)
    row.request = clean(planned_request(body, found[0].plan).stored())
    return row, trajectory, found[0]
