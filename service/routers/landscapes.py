"""Objective landscapes (synchronous, bounded, stored): ``B``, feasibility and peak joint speed
over a grid of two parameters of a method (:func:`engine.landscape`), with a heatmap figure.
Computed behind the plan admission, like plans."""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import APIRouter, Request, Response, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select
from sqlalchemy.orm import Session

from engine import axis_values, landscape
from engine.errors import ParameterError
from service import figures
from service.convert import build_task, clean, field_path, resolve_robot
from service.deps import LandscapeId, SessionDep, SessionRoute, SettingsDep, delete_row, load_row
from service.errors import ApiValidationError, NotFoundError, responses
from service.infra import jsonio
from service.infra.db import Database
from service.infra.quota import check_quota
from service.infra.settings import Settings
from service.infra.storage import pack_trajectory, unpack_trajectory
from service.models import Landscape, TuningJob
from service.routers.figures import IMAGE_RESPONSES, Format, image_response
from service.routers.plans import run_admitted
from service.schemas.landscapes import LandscapeAxis, LandscapeOut, LandscapeRequest

router = APIRouter(prefix="/v1/landscapes", tags=["landscapes"], route_class=SessionRoute)

#: Work bound of one landscape: cells x tasks x plan-steps x joints (about a microsecond each on
#: one core; the grid is spread over every core).
MAX_LANDSCAPE_JOINT_STEPS = 2e7


def _invalid(loc: list[Any], msg: str) -> ApiValidationError:
    where = ".".join(str(p) for p in loc[1:])
    return ApiValidationError(f"{where}: {msg}", [{"loc": loc, "msg": msg}])


def _axis(axis: LandscapeAxis, which: str) -> np.ndarray:
    try:
        return axis_values(axis.min, axis.max, axis.steps, axis.scale)
    except ParameterError as exc:
        raise _invalid(["body", which, exc.field], exc.reason) from None


def _marks(session: Session, body: LandscapeRequest) -> dict[str, Any]:
    """The GA optimum and tuned DLS of the tuning job named in the request."""
    job = session.get(TuningJob, body.tuning_job_id)
    loc = ["body", "tuning_job_id"]
    if job is None:
        raise _invalid(loc, f"tuning job {body.tuning_job_id!r} does not exist")
    if job.status != "succeeded" or not job.result:
        raise _invalid(loc, f"tuning job {body.tuning_job_id!r} is {job.status}: only a succeeded job has an optimum")
    if job.request.get("method") != body.method:
        raise _invalid(loc, f"tuning job {body.tuning_job_id!r} tuned {job.request.get('method')}, not {body.method}")
    baseline = job.result.get("dls_baseline") or {}
    return {
        "tuning_job_id": job.id,
        "ga_optimum": job.result.get("best_params", {}),
        "ga_objective_b": job.result.get("best_objective_b"),
        "dls_objective_b": baseline.get("objective_b"),
    }


def landscape_json(row: Landscape, grids: dict[str, np.ndarray]) -> bytes:
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


@router.post(
    "",
    operation_id="create_landscape",
    response_model=LandscapeOut,
    status_code=status.HTTP_201_CREATED,
    summary="Compute the objective landscape of two parameters of a method (synchronous) and store it",
    description="Plans every cell of the grid `x` x `y` (up to 128 x 128) on each task and returns B, feasibility "
    "and the peak joint speed per cell: what the GA searches. Bounded by its work: at most "
    f"{MAX_LANDSCAPE_JOINT_STEPS:.2g} joint-steps (cells x tasks x plan-steps x joints; a 64 x 64 grid of the paper's "
    "task is 1.5e6). `tuning_job_id` marks that job's optimum and tuned DLS on the heatmap. Answers 201 with "
    "`Location`; waits for a slot of the plan admission (503 with `Retry-After` when it is full).",
    responses=responses(404, 422),
)
async def create_landscape(body: LandscapeRequest, request: Request, settings: SettingsDep) -> Response:
    db: Database = request.app.state.db
    return await run_admitted(request, _create, db, body, settings)


def _create(db: Database, body: LandscapeRequest, settings: Settings) -> Response:
    x_values, y_values = _axis(body.x, "x"), _axis(body.y, "y")
    with db.session() as session:
        robot_id, model = resolve_robot(session, body.robot_id, body.robot)
        marks = _marks(session, body) if body.tuning_job_id else None
        session.rollback()  # no connection held while the grid is computed
        tasks = [build_task(model, t, ("body", "tasks", i)) for i, t in enumerate(body.tasks)]
        work = x_values.size * y_values.size * sum(t.n_steps + 1 for t in tasks) * model.n_joints
        if work > MAX_LANDSCAPE_JOINT_STEPS:
            raise _invalid(
                ["body"],
                f"the grid is {work:.3g} joint-steps (cells x tasks' plan-steps x joints), more than "
                f"{MAX_LANDSCAPE_JOINT_STEPS:.2g}: use fewer steps per axis, shorter tasks or a coarser dt_s",
            )
        objective = body.objective
        try:
            result = landscape(
                model,
                tasks,
                body.method,
                (body.x.name, x_values),
                (body.y.name, y_values),
                fixed=body.fixed.given() if body.fixed else None,
                weights=(objective.weights[0], objective.weights[1]),
                aggregation=objective.aggregation,
                attitude_term=objective.attitude_term,
                task_aggregation=objective.task_aggregation,
                feedback_gain=body.feedback_gain,
            )
        except ParameterError as exc:
            path = field_path(exc.field)
            if path[0] in ("x", "y"):
                path = [path[0], "min" if path[-1] in ("x", "y") else path[-1]]
            raise _invalid(["body", *path], exc.reason) from None
        summary = clean(
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
            request=clean(body.stored()),
            summary=summary,
            grids=pack_trajectory(grids),
            elapsed_s=result.elapsed_s,
        )
        check_quota(session, settings.storage_quota_bytes, len(row.grids))
        session.add(row)
        session.commit()
        content = landscape_json(row, unpack_trajectory(row.grids))
    return Response(content, status_code=201, media_type="application/json", headers={"Location": f"/v1/landscapes/{row.id}"})


def _load(session: Session, landscape_id: str) -> Landscape:
    return load_row(session, Landscape, landscape_id, "landscape")


@router.get(
    "/{landscape_id:id}",
    operation_id="get_landscape",
    response_model=LandscapeOut,
    summary="Get a stored objective landscape",
    description="The grid as computed (B per cell [x index][y index], null where infeasible).",
    responses=responses(404),
)
def get_landscape(landscape_id: LandscapeId, session: SessionDep) -> Response:
    row = _load(session, landscape_id)
    return Response(landscape_json(row, unpack_trajectory(row.grids)), media_type="application/json")


@router.delete(
    "/{landscape_id:id}",
    operation_id="delete_landscape",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a stored objective landscape",
    description="204 once deleted; 404 for an unknown id.",
    responses=responses(404),
)
def delete_landscape(landscape_id: LandscapeId, session: SessionDep) -> Response:
    return delete_row(session, Landscape, landscape_id, "landscape")


@router.get(
    "/{landscape_id:id}/figures/heatmap",
    operation_id="get_landscape_heatmap",
    summary="The heatmap of an objective landscape",
    description="log10 B over the two parameters; the infeasible region (joint speed limit broken or plan diverged) "
    "hatched grey; the grid's best cell marked; with `tuning_job_id`, the job's GA optimum (star) and the contour "
    "where B equals its tuned DLS's (inside it the method beats the tuned DLS).",
    response_class=Response,
    responses={**IMAGE_RESPONSES, **responses(404, 422)},
)
async def get_landscape_heatmap(landscape_id: LandscapeId, request: Request, format: Format = "svg") -> Response:
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_heatmap, request, landscape_id, format)
        return response


def _heatmap(request: Request, landscape_id: str, format: str) -> Response:
    with request.app.state.db.session() as session:  # a deleted landscape's figure is gone too
        if session.scalar(select(Landscape.id).where(Landscape.id == landscape_id)) is None:
            raise NotFoundError("landscape", landscape_id)

    def render() -> bytes:
        with request.app.state.db.session() as session:
            row = _load(session, landscape_id)
            data = {"id": row.id, **row.summary, "grids": unpack_trajectory(row.grids)}
        return figures.render_landscape_figure(data, format)

    content, hit = figures.cached(("landscape", landscape_id, format), render)
    return image_response(request, content, format, hit, immutable=True)
