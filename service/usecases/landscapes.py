"""Objective landscapes (synchronous, bounded, stored): ``B``, feasibility and peak joint speed
over a grid of two parameters of a method (:func:`engine.landscape`), with a heatmap figure."""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from engine import landscape
from engine.inverses import method_spec
from service import figures
from service.errors import ApiValidationError, NotFoundError
from service.infra import jsonio
from service.infra.db import Database
from service.infra.quota import check_quota
from service.infra.settings import Settings
from service.infra.storage import pack_trajectory, unpack_trajectory
from service.models import Landscape, TuningJob
from service.schemas.common import located
from service.schemas.landscapes import LandscapeRequest
from service.usecases import meshes, robots, rows

#: Work bound of one landscape: cells x tasks x plan-steps x joints (about a microsecond each on
#: one core; the grid is spread over every core).
MAX_LANDSCAPE_JOINT_STEPS = 2e7


def _marks(session: Session, body: LandscapeRequest) -> dict[str, Any]:
    """The GA optimum and tuned DLS of the tuning job named in the request."""
    job = session.get(TuningJob, body.tuning_job_id)
    loc = ["body", "tuning_job_id"]
    if job is None:
        raise ApiValidationError.at(loc, f"tuning job {body.tuning_job_id!r} does not exist")
    if job.status != "succeeded" or not job.result:
        raise ApiValidationError.at(
            loc, f"tuning job {body.tuning_job_id!r} is {job.status}: only a succeeded job has an optimum"
        )
    if job.request.get("method") != body.method:
        raise ApiValidationError.at(
            loc, f"tuning job {body.tuning_job_id!r} tuned {job.request.get('method')}, not {body.method}"
        )
    baseline = job.result.get("dls_baseline") or {}
    return {
        "tuning_job_id": job.id,
        "ga_optimum": job.result.get("best_params", {}),
        "ga_objective_b": job.result.get("best_objective_b"),
        "dls_objective_b": baseline.get("objective_b"),
    }


def body_json(row: Landscape, grids: dict[str, np.ndarray]) -> bytes:
    """The JSON body of a stored landscape (infeasible cells' B and diverged speeds as null)."""
    b = np.where(grids["feasible"] > 0.5, grids["objective_b"], np.nan)
    summary = dict(row.summary)
    axes = {k: {"name": summary.pop(f"{k}_name"), "values": grids[k], "scale": summary.pop(f"{k}_scale")} for k in ("x", "y")}
    return jsonio.dumps(
        {
            "id": row.id,
            "robot_id": row.robot_id,
            **summary,
            **axes,
            "objective_b": b,
            "feasible": grids["feasible"] > 0.5,
            "max_joint_speed_deg_s": np.degrees(grids["max_joint_speed"]),
            "created_at": row.created_at,
            "links": {"self": f"/v1/landscapes/{row.id}", "heatmap": f"/v1/landscapes/{row.id}/figures/heatmap"},
        }
    )


def create(db: Database, settings: Settings, body: LandscapeRequest) -> tuple[str, bytes]:
    """Compute and store a landscape: its id and JSON body."""
    params = {p.name: p for p in method_spec(body.method).params}
    for name, axis in (("x", body.x), ("y", body.y)):
        with located(axis, "body", name):
            if axis.name in params:  # each bound against the parameter's range: the error names the bound
                for bound in ("min", "max"):
                    params[axis.name].check(float(getattr(axis, bound)), bound)
    with located(body.x, "body", "x"):
        x_values = body.x.values()
    with located(body.y, "body", "y"):
        y_values = body.y.values()
    tasks = []
    with db.session() as session, meshes.hulls(session):
        robot_id, model = robots.resolve(session, body.robot_id, body.robot)
        marks = _marks(session, body) if body.tuning_job_id else None
        for i, task in enumerate(body.tasks):
            with located(task, "body", "tasks", i):
                tasks.append(task.to_engine(model))
    work = x_values.size * y_values.size * sum(t.n_steps + 1 for t in tasks) * model.n_joints
    if work > MAX_LANDSCAPE_JOINT_STEPS:
        raise ApiValidationError.at(
            ["body"],
            f"the grid is {work:.3g} joint-steps (cells x tasks' plan-steps x joints), more than "
            f"{MAX_LANDSCAPE_JOINT_STEPS:.2g}: use fewer steps per axis, shorter tasks or a coarser dt_s",
        )
    with located(body, "body"):
        result = landscape(
            model,
            tasks,
            body.method,
            (body.x.name, x_values),
            (body.y.name, y_values),
            fixed=body.fixed.given() if body.fixed else None,
            options=body.options(),
            task_aggregation=body.objective.task_aggregation,
        )
    summary = jsonio.clean(
        {
            "method": result.method,
            "x_name": result.x_name,
            "y_name": result.y_name,
            "x_scale": body.x.scale,
            "y_scale": body.y.scale,
            "fixed": result.fixed,
            "best_params": result.best_params,
            "best_objective_b": result.best_objective_b,
            "feasible_fraction": float(result.feasible.mean()),
            "marks": marks,
            "evaluations": result.evaluations,
            "elapsed_s": result.elapsed_s,
        }
    )
    grids = {
        "x": result.x_values,
        "y": result.y_values,
        "objective_b": np.where(result.feasible, result.objective_b, np.nan),
        "feasible": result.feasible.astype(float),
        "max_joint_speed": result.max_joint_speed,
    }
    row = Landscape(
        robot_id=robot_id,
        request=jsonio.clean(body.stored()),
        summary=summary,
        grids=pack_trajectory(grids),
        elapsed_s=result.elapsed_s,
    )
    with db.session() as session:
        check_quota(session, settings.storage_quota_bytes, len(row.grids))
        session.add(row)
        session.commit()
        return row.id, body_json(row, unpack_trajectory(row.grids))


def load(session: Session, landscape_id: str) -> Landscape:
    return rows.load(session, Landscape, landscape_id, "landscape")


def delete(db: Database, landscape_id: str) -> None:
    rows.delete(db, Landscape, landscape_id, "landscape")


def read(session: Session, landscape_id: str) -> bytes:
    row = load(session, landscape_id)
    return body_json(row, unpack_trajectory(row.grids))


def heatmap(db: Database, landscape_id: str, fmt: str, dpi: int | None = None) -> tuple[bytes, bool]:
    """The heatmap figure (``(bytes, cache hit)``); a deleted landscape's figure is gone too."""
    with db.session() as session:
        if session.scalar(select(Landscape.id).where(Landscape.id == landscape_id)) is None:
            raise NotFoundError("landscape", landscape_id)

    def render() -> bytes:
        with db.session() as session:
            row = load(session, landscape_id)
            data = {
                "id": row.id,
                **row.summary,
                "objective": row.request.get("objective"),
                "grids": unpack_trajectory(row.grids),
            }
        return figures.render_landscape_figure(data, fmt, dpi)

    return figures.cached(("landscape", landscape_id, fmt, dpi), render)
