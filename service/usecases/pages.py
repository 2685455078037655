"""What the web pages show: the index's robots, recent plans and jobs; a plan's and a job's page."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select

from engine.inverses import METHODS, Param
from engine.metrics import LAYOUT
from service.infra.db import Database
from service.models import Plan, Robot, TuningJob

#: The plan page's metrics card: (API name, label, unit shown, scale), from the metrics layout.
METRIC_ROWS = [(spec.api, spec.web.label, spec.web.unit, spec.web.scale) for spec in LAYOUT if spec.web is not None]


def method_forms() -> list[dict[str, Any]]:
    return [
        {
            "name": name,
            "description": spec.description,
            "params": [{"name": p.name, "default": p.default, "unit": p.unit} for p in spec.params],
        }
        for name, spec in METHODS.items()
    ]


def method_params(name: str) -> tuple[Param, ...]:
    """The parameters of the method ``name`` (none for an unknown name: the API refuses it)."""
    spec = METHODS.get(name)
    return spec.params if spec is not None else ()


def index(db: Database) -> dict[str, Any]:
    with db.session() as s:
        robots = s.scalars(select(Robot).order_by(Robot.created_at, Robot.id).limit(50)).all()
        plans = s.execute(
            select(Plan.id, Plan.robot_id, Plan.method, Plan.success, Plan.metrics, Plan.created_at)
            .order_by(Plan.created_at.desc(), Plan.id)
            .limit(20)
        ).all()
        jobs = s.scalars(select(TuningJob).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(20)).all()
        return {
            "robots": [
                {"id": r.id, "name": r.name, "preset": r.preset, "n_joints": len(r.parameters.get("links", []))} for r in robots
            ],
            "plans": [r._asdict() for r in plans],
            "jobs": [
                {
                    "id": j.id,
                    "status": j.status,
                    "method": j.request.get("method"),
                    "progress": j.progress or {},
                    "created_at": j.created_at,
                }
                for j in jobs
            ],
        }


def plan(db: Database, plan_id: str) -> dict[str, Any] | None:
    with db.session() as s:
        row = s.execute(
            select(
                Plan.id,
                Plan.robot_id,
                Plan.method,
                Plan.success,
                Plan.message,
                Plan.metrics,
                Plan.replay,
                Plan.elapsed_s,
                Plan.created_at,
            ).where(Plan.id == plan_id)
        ).first()
    return None if row is None else row._asdict()


def job(db: Database, job_id: str) -> dict[str, Any] | None:
    with db.session() as s:
        row = s.get(TuningJob, job_id)
        if row is None:
            return None
        return {
            "id": row.id,
            "status": row.status,
            "method": row.request.get("method"),
            "request": row.request,
            "progress": row.progress or {},
            "result": row.result,
            "error": row.error,
            "created_at": row.created_at,
        }
