"""Synchronous plans. Handlers are plain ``def`` functions, so FastAPI runs them in its thread
pool and a long plan never blocks the event loop."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Query, Response, status
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from engine import RobotModel, make_inverse, plan, replay
from engine.inverses import METHODS
from service.convert import build_task, clean, metrics_out, replay_out, robot_model, trajectory_out
from service.deps import SessionDep
from service.errors import ApiValidationError, NotFoundError, responses
from service.models import Plan, Robot
from service.schemas import PlanList, PlanOut, PlanRequest, PlanSummary, RobotParams

router = APIRouter(prefix="/v1/plans", tags=["plans"])


def resolve_robot(session: Session, robot_id: str | None, inline: RobotParams | None) -> tuple[str | None, RobotModel]:
    """The robot of a request: inline parameters win over ``robot_id``."""
    if inline is not None:
        return None, robot_model(inline.model_dump(exclude_none=True), ("body", "robot"))
    if robot_id is None:
        raise ApiValidationError(
            "give either robot_id (a stored robot, e.g. 'table1') or an inline robot",
            [{"loc": ["body", "robot_id"], "msg": "robot_id or robot is required"}],
        )
    robot = session.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError("robot", robot_id)
    return robot.id, robot_model(robot.parameters)


def check_method(name: str, params: dict[str, float], loc: tuple[str, ...] = ("body", "method")) -> Any:
    if name not in METHODS:
        raise ApiValidationError(
            f"unknown method {name!r}; valid methods: {', '.join(METHODS)}",
            [{"loc": [*loc, "name"], "msg": f"must be one of {', '.join(METHODS)}"}],
        )
    try:
        return make_inverse(name, **params)
    except ValueError as exc:
        raise ApiValidationError(f"method.params: {exc}", [{"loc": [*loc, "params"], "msg": str(exc)}]) from None


def plan_summary(p: Plan) -> PlanSummary:
    return PlanSummary(
        id=p.id,
        robot_id=p.robot_id,
        method=p.method,
        success=p.success,
        message=p.message,
        metrics=p.metrics,  # type: ignore[arg-type]
        elapsed_s=p.elapsed_s,
        created_at=p.created_at,
    )


def plan_out(p: Plan) -> PlanOut:
    return PlanOut(**plan_summary(p).model_dump(), trajectory=p.trajectory, replay=p.replay)  # type: ignore[arg-type]


@router.post(
    "",
    operation_id="create_plan",
    response_model=PlanOut,
    status_code=status.HTTP_201_CREATED,
    summary="Plan a Cartesian task (synchronous) and store the plan",
    responses=responses(404, 422),
)
def create_plan(body: PlanRequest, session: SessionDep, response: Response) -> PlanOut:
    robot_id, model = resolve_robot(session, body.robot_id, body.robot)
    task = build_task(model, body.task)
    inverse = check_method(body.method.name, body.method.params)
    try:
        weights = (body.weights[0], body.weights[1])
        start = time.perf_counter()
        result = plan(model, task, inverse, feedback_gain=body.feedback_gain, weights=weights, aggregation=body.aggregation)
        checked = replay(model, result) if body.replay else None
        elapsed = time.perf_counter() - start
    except ValueError as exc:
        raise ApiValidationError(str(exc), [{"loc": ["body"], "msg": str(exc)}]) from None
    row = Plan(
        robot_id=robot_id,
        request=clean(body.model_dump(mode="json")),
        method=clean({"name": result.method, "params": result.params}),
        success=result.success,
        message=result.message,
        metrics=metrics_out(result.metrics),
        trajectory=trajectory_out(result),
        replay=replay_out(checked) if checked is not None else None,
        elapsed_s=elapsed,
    )
    session.add(row)
    session.commit()  # before the response goes out: a client's next request must see it
    response.headers["Location"] = f"/v1/plans/{row.id}"
    return plan_out(row)


@router.get("", operation_id="list_plans", response_model=PlanList, summary="List stored plans (without trajectories)")
def list_plans(session: SessionDep, limit: int = Query(50, ge=1, le=500), offset: int = Query(0, ge=0)) -> PlanList:
    total = session.scalar(select(func.count()).select_from(Plan)) or 0
    rows = session.execute(
        select(Plan.id, Plan.robot_id, Plan.method, Plan.success, Plan.message, Plan.metrics, Plan.elapsed_s, Plan.created_at)
        .order_by(Plan.created_at.desc(), Plan.id)
        .limit(limit)
        .offset(offset)
    ).all()
    return PlanList(items=[PlanSummary(**r._asdict()) for r in rows], total=total)


@router.get("/{plan_id}", operation_id="get_plan", response_model=PlanOut, summary="Get a stored plan", responses=responses(404))
def get_plan(plan_id: str, session: SessionDep) -> PlanOut:
    row = session.get(Plan, plan_id)
    if row is None:
        raise NotFoundError("plan", plan_id)
    return plan_out(row)
