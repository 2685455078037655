"""Synchronous plans. Handlers are plain ``def`` functions, so FastAPI runs them in its thread
pool and a long plan never blocks the event loop."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from fastapi import APIRouter, Query, Response, status
from sqlalchemy import func, select

from engine import PlanResult, make_inverse, plan, replay
from engine.errors import ParameterError
from service.convert import build_task, clean, field_path, metrics_out, replay_out, resolve_robot, trajectory_out
from service.deps import SessionDep, SettingsDep
from service.errors import MAX_OFFSET, ApiValidationError, NotFoundError, responses
from service.models import Plan
from service.schemas import PlanList, PlanOut, PlanRequest, PlanSummary, ReplayOut

router = APIRouter(prefix="/v1/plans", tags=["plans"])


def check_method(name: str, params: dict[str, float], loc: tuple[str, ...] = ("body", "method")) -> Any:
    """The engine's strategy for ``name``; unknown names and bad parameters are 422s naming
    ``method.name`` or ``method.params.<parameter>``."""
    try:
        return make_inverse(name, **params)
    except ParameterError as exc:
        path = [*loc, "name"] if exc.field == "method" else [*loc, "params", exc.field]
        where = ".".join(str(p) for p in path[1:])
        raise ApiValidationError(f"{where}: {exc.reason}", [{"loc": path, "msg": exc.reason}]) from None


REPLAY_MAX_TRAVEL_RAD = 200.0


def replay_skip_reason(result: PlanResult, max_steps: int) -> str | None:
    """Why a plan is not replayed synchronously, or None. ``solve_ivp`` (tight tolerances) costs
    about 7 ms per step and more the further the joints turn: a plan longer than ``max_steps``
    (``SPACEARM_MAX_REPLAY_STEPS``) or a diverged plan with absurd joint rates (found by the fuzz:
    1e10 deg/s) would keep the request busy for minutes."""
    qd = np.nan_to_num(np.abs(result.qd), nan=np.inf)
    dt = np.diff(result.t)
    if dt.shape[0] > max_steps:
        return (
            f"not replayed: {dt.shape[0]} steps, more than the {max_steps} replayed synchronously "
            "(SPACEARM_MAX_REPLAY_STEPS); replay it with the engine's replay() offline"
        )
    if qd.shape[0] < dt.shape[0] or dt.shape[0] == 0:
        return None
    travel = float(np.sum(np.max(qd[: dt.shape[0]], axis=1) * dt))
    if not math.isfinite(travel):
        return "not replayed: the plan is not finite"
    if travel > REPLAY_MAX_TRAVEL_RAD:
        return (
            f"not replayed: the planned joints turn {travel:.3g} rad in all (more than {REPLAY_MAX_TRAVEL_RAD:g} rad), "
            "the plan is not physically meaningful"
        )
    return None


def not_replayed(reason: str) -> dict[str, Any]:
    fields = [name for name in ReplayOut.model_fields if name not in ("success", "message")]
    return {"success": False, "message": reason, **dict.fromkeys(fields)}


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
def create_plan(body: PlanRequest, session: SessionDep, settings: SettingsDep, response: Response) -> PlanOut:
    robot_id, model = resolve_robot(session, body.robot_id, body.robot)
    task = build_task(model, body.task)
    inverse = check_method(body.method.name, body.method.params)
    try:
        start = time.perf_counter()
        result = plan(
            model,
            task,
            inverse,
            feedback_gain=body.feedback_gain,
            weights=(body.weights[0], body.weights[1]),
            aggregation=body.aggregation,
            attitude_term=body.attitude_term,
        )
        skipped = replay_skip_reason(result, settings.max_replay_steps) if body.replay else None
        checked = replay(model, result) if body.replay and skipped is None else None
        elapsed = time.perf_counter() - start
    except ParameterError as exc:
        loc = ["body", *field_path(exc.field)]
        raise ApiValidationError(str(exc), [{"loc": loc, "msg": exc.reason}]) from None
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
        replay=replay_out(checked) if checked is not None else (not_replayed(skipped) if skipped else None),
        elapsed_s=elapsed,
    )
    session.add(row)
    session.commit()  # before the response goes out: a client's next request must see it
    response.headers["Location"] = f"/v1/plans/{row.id}"
    return plan_out(row)


@router.get("", operation_id="list_plans", response_model=PlanList, summary="List stored plans (without trajectories)")
def list_plans(
    session: SessionDep, limit: int = Query(50, ge=1, le=500), offset: int = Query(0, ge=0, le=MAX_OFFSET)
) -> PlanList:
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
