"""Figures of stored plans, tuning jobs and landscapes: what to load from the database for
:mod:`service.figures`, and the render cache's keys."""

from __future__ import annotations

import functools
from typing import Any

from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from engine.errors import ParameterError
from engine.geometry import Shape
from service import figures
from service.errors import ApiValidationError, NotFoundError
from service.infra.db import Database
from service.infra.storage import unpack_trajectory
from service.models import Plan, Robot, TuningJob
from service.schemas.geometry import SceneIn
from service.schemas.robots import RobotParams
from service.usecases import meshes, tuning_jobs
from service.usecases.plans import record_from_storage

#: Plans on one comparison figure, at most.
MAX_COMPARE = 8


def robot_parameters(session: Session, p: Plan) -> dict[str, Any] | None:
    """The parameters of the robot a plan was made for: the stored robot, or the request's inline one."""
    if p.robot_id is not None:
        robot = session.get(Robot, p.robot_id)
        return dict(robot.parameters) if robot is not None else None
    inline = (p.request or {}).get("robot")
    if not isinstance(inline, dict):
        return None
    try:  # the stored request keeps the optional fields it left out as nulls: drop them
        return RobotParams.model_validate(inline).model_dump(mode="json", exclude_none=True)
    except ValidationError:
        return None


def obstacles(session: Session, request: dict[str, Any] | None) -> tuple[Shape | None, ...]:
    """The obstacles of a stored plan's request (world frame; a mesh by its stored hull), none
    when the request has none; None in place of one this version cannot read (a mesh deleted
    since), so that the others keep their names (``obstacle<i>``, as the plan's metrics name them;
    a deleted mesh took every obstacle with it)."""
    scene = ((request or {}).get("task") or {}).get("scene")
    if not isinstance(scene, dict) or not scene.get("obstacles"):
        return ()
    with meshes.hulls(session):
        try:
            return SceneIn.model_validate(scene).to_engine(0.0).obstacles
        except (ValidationError, ParameterError):
            pass
        return tuple(_obstacle(obstacle) for obstacle in scene["obstacles"])


def _obstacle(obstacle: Any) -> Shape | None:
    try:
        (shape,) = SceneIn.model_validate({"obstacles": [obstacle]}).to_engine(0.0).obstacles
    except (ValidationError, ParameterError, ValueError):
        return None
    return shape


def plan_data(session: Session, row: Plan, with_robot: bool = True) -> figures.PlanData:
    """A stored plan as the figures read it."""
    data = figures.PlanData(
        record_from_storage(unpack_trajectory(row.trajectory_data)),
        plan_id=row.id,
        method=row.method,
        metrics=row.metrics,
        request=row.request,
        robot=robot_parameters(session, row) if with_robot else None,
    )
    data.obstacles = obstacles(session, row.request)
    return data


def plan_figure(db: Database, plan_id: str, name: str, fmt: str, dpi: float | None = None) -> tuple[bytes, bool]:
    """A plan's figure (``(bytes, cache hit)``) at ``dpi`` (None: the default); a deleted plan's
    figures are gone too."""
    with db.session() as session:
        if session.scalar(select(Plan.id).where(Plan.id == plan_id)) is None:
            raise NotFoundError("plan", plan_id)

    def load() -> figures.PlanData:
        with db.session() as session:
            row = session.get(Plan, plan_id)
            if row is None:
                raise NotFoundError("plan", plan_id)
            return plan_data(session, row)

    return figures.cached(
        ("plan", plan_id, name, fmt, dpi),
        lambda: figures.render_plan_figure(figures.plan_data(plan_id, load), name, fmt, dpi),
    )


def compare_figure(db: Database, name: str, ids: str, fmt: str, dpi: float | None = None) -> tuple[bytes, bool]:
    """Several plans on one figure: the plan figure ``name`` of each, side by side
    (:func:`service.figures.fig_compare`); the 3D scene needs the robots."""
    plan_ids = list(dict.fromkeys(i.strip() for i in ids.split(",") if i.strip()))
    if not plan_ids or len(plan_ids) > MAX_COMPARE:
        raise ApiValidationError.at(
            ["query", "ids"], f"1 to {MAX_COMPARE} comma-separated ids", detail=f"give 1 to {MAX_COMPARE} plan ids"
        )

    def render() -> bytes:
        with db.session() as session:
            rows = {p.id: p for p in session.scalars(select(Plan).where(Plan.id.in_(plan_ids))).all()}
            for pid in plan_ids:
                if pid not in rows:
                    raise NotFoundError("plan", pid)
            data = [figures.plan_data(pid, functools.partial(plan_data, session, rows[pid])) for pid in plan_ids]
        return figures.render_compare_figure(data, fmt, dpi, name=name)

    return figures.cached(("compare", name, tuple(plan_ids), fmt, dpi), render)


def job_figure(db: Database, job_id: str, name: str, fmt: str, dpi: float | None = None) -> tuple[bytes, bool]:
    """A tuning job's figure, refreshed while the job runs (its version is in the cache key)."""
    with db.session() as session:
        row = session.get(TuningJob, job_id)
        if row is None:
            raise NotFoundError("tuning job", job_id)
        history = [
            {k: getattr(r, k) for k in ("phase", "role", "generation", "best", "mean", "feasible")}
            for r in tuning_jobs.history(session, [row])[row.id]
        ]
        job: dict[str, Any] = {
            "id": row.id,
            "status": row.status,
            "method": row.request.get("method"),
            "objective": row.request.get("objective"),
            "progress": row.progress,
            "history": history,
            "result": row.result,
            "updated_at": row.updated_at.isoformat() if row.updated_at else None,
        }
    version = (job["status"], len(history), job["updated_at"])
    return figures.cached(("job", job_id, name, fmt, dpi, version), lambda: figures.render_job_figure(job, fmt, dpi))
