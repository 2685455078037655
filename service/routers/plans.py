"""Synchronous plans. A plan request waits for a slot of the plan admission
(:mod:`service.infra.admission`: a few plans at once, a short queue, then 503 with ``Retry-After``) on
the event loop, then runs in the thread pool (the engine's kernels release the GIL, so plans run
in parallel on every core). Reads are plain ``def`` handlers in the thread pool.

Plan bodies are written once, by orjson from the planner's arrays (:mod:`service.infra.jsonio`): the
trajectory is neither copied into Python lists nor validated again on the way out. Trajectories
are stored as compressed arrays (:mod:`service.infra.storage`). ``fields`` leaves out the large
sections."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from engine import PlanResult, RobotModel, make_inverse, make_secondary, plan, replay
from engine.errors import ParameterError
from engine.redundancy import SecondaryObjective
from service.convert import build_task, clean, field_path, metrics_out, replay_out, resolve_robot, trajectory_out
from service.deps import Limit, Offset, PlanId, SessionDep, SessionRoute, SettingsDep, delete_row
from service.errors import ApiValidationError, NotFoundError, responses
from service.infra import jsonio
from service.infra.db import Database
from service.infra.metrics import count_plan
from service.infra.quota import check_quota
from service.infra.settings import Settings
from service.infra.storage import pack_trajectory, unpack_trajectory
from service.models import Plan
from service.schemas.plans import PLAN_SECTIONS, PlanList, PlanOut, PlanRequest, PlanSummary, ReplayOut

router = APIRouter(prefix="/v1/plans", tags=["plans"], route_class=SessionRoute)


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


_SECTION = "(" + "|".join(PLAN_SECTIONS) + ")"
#: A comma-separated list of sections (spaces and empty items allowed), or nothing.
SECTIONS_PATTERN = rf"^\s*{_SECTION}?\s*(,\s*{_SECTION}?\s*)*$"
FieldsQuery = Annotated[
    str | None,
    Query(
        max_length=200,
        # In the document only: parse_fields names the unknown sections in its 422.
        json_schema_extra={"pattern": SECTIONS_PATTERN},
        description="comma-separated sections of the plan to return besides its summary (id, method, success, "
        f"message, metrics, ...): any of {', '.join(f'`{name}`' for name in PLAN_SECTIONS)}; default all, "
        "empty for the summary only",
        examples=["replay"],
    ),
]


def parse_fields(fields: str | None) -> set[str]:
    """The sections asked for; unknown names are a 422 naming the valid ones."""
    if fields is None:
        return set(PLAN_SECTIONS)
    names = {name.strip() for name in fields.split(",") if name.strip()}
    unknown = sorted(names - set(PLAN_SECTIONS))
    if unknown:
        msg = f"unknown section(s) {', '.join(unknown)}; valid: {', '.join(PLAN_SECTIONS)}"
        raise ApiValidationError(f"fields: {msg}", [{"loc": ["query", "fields"], "msg": msg}])
    return names


SUMMARY_COLUMNS = (Plan.id, Plan.robot_id, Plan.method, Plan.success, Plan.message, Plan.metrics, Plan.elapsed_s, Plan.created_at)


def plan_summary(p: Plan) -> PlanSummary:
    return PlanSummary(
        id=p.id,
        robot_id=p.robot_id,
        method=p.method,  # type: ignore[arg-type]
        success=p.success,
        message=p.message,
        metrics=p.metrics,  # type: ignore[arg-type]
        elapsed_s=p.elapsed_s,
        created_at=p.created_at,
    )


def plan_json(summary: PlanSummary, sections: dict[str, Any]) -> bytes:
    """The JSON body of a plan: its summary and ``sections`` (numpy arrays allowed)."""
    return jsonio.dumps_large({**summary.model_dump(mode="json"), **sections})


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
    sections = parse_fields(fields)
    db: Database = request.app.state.db
    return await run_admitted(request, store_plan, db, settings, sections, lambda session: compute_plan(session, body, settings))


async def run_admitted(request: Request, work: Callable[..., Response], *args: Any) -> Response:
    """Run ``work(*args)`` in the thread pool once the plan admission lets it in."""
    async with request.app.state.plan_admission.slot():
        response: Response = await run_in_threadpool(work, *args)
        return response


def store_plan(
    db: Database,
    settings: Settings,
    sections: set[str],
    compute: Callable[[Session], tuple[Plan, dict[str, np.ndarray]]],
    wrap: Callable[[bytes], bytes] = lambda plan: plan,
) -> Response:
    """Compute a plan (``compute``: the row and its trajectory arrays), store it within the
    quota and answer 201 with ``wrap`` of its JSON body and its ``Location``."""
    with db.session() as session:
        row, trajectory = compute(session)
        check_quota(session, settings.storage_quota_bytes, len(row.trajectory_data))
        session.add(row)
        session.commit()  # before the response goes out: a client's next request must see it
    count_plan(row.method["name"], row.success, row.elapsed_s)
    parts = {"trajectory": trajectory, "replay": row.replay}
    content = wrap(plan_json(plan_summary(row), {name: parts[name] for name in PLAN_SECTIONS if name in sections}))
    return Response(content, status_code=201, media_type="application/json", headers={"Location": f"/v1/plans/{row.id}"})


def compute_plan(session: Session, body: PlanRequest, settings: Settings) -> tuple[Plan, dict[str, np.ndarray]]:
    """Plan (and replay) a request: the row to store and the trajectory arrays."""
    robot_id, model = resolve_robot(session, body.robot_id, body.robot)
    session.rollback()  # end the read: no connection is held while the plan is computed
    task = build_task(model, body.task)
    inverse = check_method(body.method.name, body.method.params.given())
    return finish_plan(
        body,
        robot_id,
        model,
        settings,
        lambda: plan(model, task, inverse, **plan_options(body)),
    )


def plan_options(body: PlanRequest) -> dict[str, Any]:
    """The engine's plan keywords of a request (feedback gain and objective)."""
    return {
        "feedback_gain": body.feedback_gain,
        "weights": (body.weights[0], body.weights[1]),
        "aggregation": body.aggregation,
        "attitude_term": body.attitude_term,
        "secondary": secondary_objective(body),
    }


def secondary_objective(body: PlanRequest) -> SecondaryObjective | None:
    """The engine's null-space objective of a request (its default gain filled in), if any."""
    return make_secondary(body.secondary.objective, body.secondary.gain) if body.secondary is not None else None


def finish_plan(
    body: PlanRequest, robot_id: str | None, model: RobotModel, settings: Settings, make: Callable[[], PlanResult]
) -> tuple[Plan, dict[str, np.ndarray]]:
    """Run ``make`` (the engine's plan of ``body``), replay it if asked: the row to store and the
    trajectory arrays; engine errors are 422s naming the field."""
    try:
        start = time.perf_counter()
        result = make()
        skipped = replay_skip_reason(result, settings.max_replay_steps) if body.replay else None
        checked = replay(model, result) if body.replay and skipped is None else None
        elapsed = time.perf_counter() - start
    except ParameterError as exc:
        loc = ["body", *field_path(exc.field)]
        raise ApiValidationError(str(exc), [{"loc": loc, "msg": exc.reason}]) from None
    except ValueError as exc:
        raise ApiValidationError(str(exc), [{"loc": ["body"], "msg": str(exc)}]) from None
    trajectory = trajectory_out(result, model.prismatic)
    row = Plan(
        robot_id=robot_id,
        request=clean(body.stored()),
        method=clean(
            {
                "name": result.method,
                "params": result.params,
                **({"secondary": {"objective": sec.name, "gain": sec.gain}} if (sec := secondary_objective(body)) else {}),
            }
        ),
        success=result.success,
        message=result.message,
        metrics=metrics_out(result.metrics),
        trajectory_data=pack_trajectory(trajectory),
        replay=replay_out(checked) if checked is not None else (not_replayed(skipped) if skipped else None),
        elapsed_s=elapsed,
    )
    return row, trajectory


def rehearse(db: Database, settings: Settings) -> None:
    """Take the OpenAPI example of a plan request through every step of :func:`create_plan`,
    the database insert included, and roll it back: the API's start-up runs it so that the first
    real request finds the connection, the compiled statements and the code paths warm."""
    body = PlanRequest.model_validate(PlanRequest.model_config["json_schema_extra"]["examples"][0])  # type: ignore[index]
    with db.sessionmaker() as session:
        try:
            row, trajectory = compute_plan(session, body, settings)
            session.add(row)
            session.flush()
            plan_json(plan_summary(row), {"trajectory": trajectory, "replay": row.replay})
            check_quota(session, settings.storage_quota_bytes, len(row.trajectory_data))
            found = session.execute(select(*SUMMARY_COLUMNS, Plan.replay, Plan.trajectory_data).where(Plan.id == row.id)).one()
            unpack_trajectory(found[-1])
        finally:
            session.rollback()


@router.get(
    "",
    operation_id="list_plans",
    response_model=PlanList,
    summary="List stored plans (without trajectories)",
    description="Stored plans, newest first, `limit` at a time from `offset`: each plan's summary (method, verdict, "
    "metrics); `total` counts them all.",
)
def list_plans(session: SessionDep, limit: Limit = 50, offset: Offset = 0) -> PlanList:
    total = session.scalar(select(func.count()).select_from(Plan)) or 0
    rows = session.execute(
        select(Plan.id, Plan.robot_id, Plan.method, Plan.success, Plan.message, Plan.metrics, Plan.elapsed_s, Plan.created_at)
        .order_by(Plan.created_at.desc(), Plan.id)
        .limit(limit)
        .offset(offset)
    ).all()
    return PlanList(items=[PlanSummary(**r._asdict()) for r in rows], total=total)


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
    sections = parse_fields(fields)
    columns: list[Any] = [*SUMMARY_COLUMNS, Plan.replay]
    if "trajectory" in sections:
        columns.append(Plan.trajectory_data)
    found = session.execute(select(*columns).where(Plan.id == plan_id)).first()
    if found is None:
        raise NotFoundError("plan", plan_id)
    summary = PlanSummary(**{c.key: v for c, v in zip(SUMMARY_COLUMNS, found, strict=False)})
    parts = {"replay": found[len(SUMMARY_COLUMNS)]}
    if "trajectory" in sections:
        parts["trajectory"] = unpack_trajectory(found[-1])
    return Response(
        plan_json(summary, {name: parts[name] for name in PLAN_SECTIONS if name in sections}), media_type="application/json"
    )


@router.delete(
    "/{plan_id:id}",
    operation_id="delete_plan",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a stored plan",
    description="204 once deleted; 404 for an unknown id. Its figures are no longer served.",
    responses=responses(404),
)
def delete_plan(plan_id: PlanId, session: SessionDep) -> Response:
    return delete_row(session, Plan, plan_id, "plan")
