"""Figures of plans and tuning jobs (SVG or PNG, rendered by :mod:`service.figures`).

Plan and job ids are matched as 32 hex digits (``{plan_id:id}``), so
``/v1/plans/compare/figures/tracking-errors`` is never read as the figure of a plan ``compare``."""

from __future__ import annotations

import hashlib
from functools import partial
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.orm import Session
from typing_extensions import TypeAliasType

from service import figures
from service.deps import JobId, PlanId, SessionRoute
from service.errors import ApiError, ApiValidationError, NotFoundError, responses
from service.infra.storage import unpack_trajectory
from service.models import Plan, Robot, TuningJob
from service.schemas.robots import RobotParams

router = APIRouter(tags=["figures"], route_class=SessionRoute)

FigureFormat = TypeAliasType("FigureFormat", Literal["svg", "png"])
assert set(FigureFormat.__value__.__args__) == set(figures.FORMATS)
Format = Annotated[FigureFormat, Query(description="`svg` (default, image/svg+xml) or `png` (image/png)")]
MAX_COMPARE = 8


def figure_name(names: tuple[str, ...] | list[str]) -> Any:
    """A figure name in the path: an enum in the document (so clients type it); an unknown name
    is still answered by the handler, a 404 whose ``valid_names`` lists the names."""
    return Path(description="the figure", json_schema_extra={"enum": list(names)})


#: The image (binary: SVG is text, but clients should store the bytes as they come), and a 304
#: for a conditional request whose ``If-None-Match`` names the current ``ETag``.
IMAGE_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "the figure: SVG (`format=svg`, the default) or PNG (`format=png`)",
        "content": {media: {"schema": {"type": "string", "format": "binary"}} for media in ("image/svg+xml", "image/png")},
        "headers": {
            "ETag": {"description": "the figure's version; send it back in `If-None-Match`", "schema": {"type": "string"}},
            "Cache-Control": {
                "description": "`public, max-age=86400` for plan figures (a plan never changes), `no-cache` for a job's",
                "schema": {"type": "string"},
            },
        },
    },
    304: {"description": "not modified: `If-None-Match` names the current `ETag`"},
}


class UnknownFigureError(ApiError):
    def __init__(self, name: str, valid: tuple[str, ...] | list[str]) -> None:
        super().__init__(
            404,
            f"unknown figure {name!r}; valid names: {', '.join(valid)}",
            type_="https://spacearm.example/problems/unknown-figure",
            valid_names=list(valid),
        )


def image_response(request: Request, content: bytes, fmt: str, hit: bool, immutable: bool) -> Response:
    etag = '"' + hashlib.sha1(content).hexdigest() + '"'
    headers = {
        "ETag": etag,
        "X-Figure-Cache": "hit" if hit else "miss",
        "Cache-Control": "public, max-age=86400" if immutable else "no-cache",
    }
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    return Response(content, media_type=figures.FORMATS[fmt], headers=headers)


def plan_dict(p: Plan, robot: dict[str, Any] | None = None) -> dict[str, Any]:
    """A stored plan as the figures read it; ``robot`` the robot's parameters (to draw the arm)."""
    return {
        "id": p.id,
        "method": p.method,
        "metrics": p.metrics,
        "request": p.request,
        "trajectory": unpack_trajectory(p.trajectory_data),
        "robot": robot,
    }


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


@router.get(
    "/v1/plans/compare/figures/{name}",
    operation_id="compare_plans_figure",
    summary="Several plans on one figure (e.g. DLS versus GA-tuned adaptive damping)",
    description="`ids` is a comma-separated list of plan ids (at most 8). Names: "
    + ", ".join(f"`{n}`" for n in figures.COMPARE_FIGURES),
    response_class=Response,
    responses={**IMAGE_RESPONSES, **responses(404, 422)},
)
async def compare_plans_figure(
    name: Annotated[str, figure_name(figures.COMPARE_FIGURES)],
    request: Request,
    ids: Annotated[str, Query(description="comma-separated plan ids", min_length=1, max_length=2000)],
    format: Format = "svg",
) -> Response:
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_compare_plans_figure, name, request, ids, format)
        return response


def _compare_plans_figure(name: str, request: Request, ids: str, format: str) -> Response:
    if name not in figures.COMPARE_FIGURES:
        raise UnknownFigureError(name, figures.COMPARE_FIGURES)
    plan_ids = list(dict.fromkeys(i.strip() for i in ids.split(",") if i.strip()))
    if not plan_ids or len(plan_ids) > MAX_COMPARE:
        raise ApiValidationError(
            f"ids: give 1 to {MAX_COMPARE} plan ids",
            [{"loc": ["query", "ids"], "msg": f"1 to {MAX_COMPARE} comma-separated ids"}],
        )

    def render() -> bytes:
        with request.app.state.db.session() as session:
            rows = {p.id: p for p in session.scalars(select(Plan).where(Plan.id.in_(plan_ids))).all()}
            for pid in plan_ids:
                if pid not in rows:
                    raise NotFoundError("plan", pid)
            data = [figures.plan_data(pid, partial(plan_dict, rows[pid])) for pid in plan_ids]
        return figures.render_compare_figure(data, format)

    content, hit = figures.cached(("compare", name, tuple(plan_ids), format), render)
    return image_response(request, content, format, hit, immutable=True)


@router.get(
    "/v1/plans/{plan_id:id}/figures/{name}",
    operation_id="get_plan_figure",
    summary="A figure of a stored plan (the paper's Figs. 4 to 11; `scene-3d` is Fig. 10's 3D view)",
    description="Names: "
    + ", ".join(f"`{n}`" for n in figures.PLAN_FIGURES)
    + ". Axes carry units; the singular region (smallest singular value below the plan's epsilon, "
    f"or {figures.DEFAULT_SINGULAR_THRESHOLD} for methods without one) is shaded. "
    "An unknown name is a 404 whose `valid_names` lists the names.",
    response_class=Response,
    responses={**IMAGE_RESPONSES, **responses(404, 422)},
)
async def get_plan_figure(
    plan_id: PlanId, name: Annotated[str, figure_name(list(figures.PLAN_FIGURES))], request: Request, format: Format = "svg"
) -> Response:
    if name not in figures.PLAN_FIGURES:
        raise UnknownFigureError(name, list(figures.PLAN_FIGURES))
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_plan_figure, plan_id, name, request, format)
        return response


def _plan_figure(plan_id: PlanId, name: str, request: Request, format: str) -> Response:
    with request.app.state.db.session() as session:  # a deleted plan's figures are gone too
        if session.scalar(select(Plan.id).where(Plan.id == plan_id)) is None:
            raise NotFoundError("plan", plan_id)

    def load() -> dict[str, Any]:
        with request.app.state.db.session() as session:
            row = session.get(Plan, plan_id)
            if row is None:
                raise NotFoundError("plan", plan_id)
            return plan_dict(row, robot_parameters(session, row))

    content, hit = figures.cached(
        ("plan", plan_id, name, format), lambda: figures.render_plan_figure(figures.plan_data(plan_id, load), name, format)
    )
    return image_response(request, content, format, hit, immutable=True)


@router.get(
    "/v1/tuning-jobs/{job_id:id}/figures/{name}",
    operation_id="get_tuning_job_figure",
    summary="A figure of a tuning job: `convergence` (best and mean B per generation, paper Fig. 7)",
    description="Updated while the job runs, from the per-generation history in its progress.",
    response_class=Response,
    responses={**IMAGE_RESPONSES, **responses(404, 422)},
)
async def get_tuning_job_figure(
    job_id: JobId, name: Annotated[str, figure_name(figures.JOB_FIGURES)], request: Request, format: Format = "svg"
) -> Response:
    if name not in figures.JOB_FIGURES:
        raise UnknownFigureError(name, figures.JOB_FIGURES)
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_job_figure, job_id, name, request, format)
        return response


def _job_figure(job_id: JobId, name: str, request: Request, format: str) -> Response:
    with request.app.state.db.session() as session:
        row = session.get(TuningJob, job_id)
        if row is None:
            raise NotFoundError("tuning job", job_id)
        job: dict[str, Any] = {
            "id": row.id,
            "status": row.status,
            "method": row.request.get("method"),
            "progress": row.progress,
            "result": row.result if row.result and not (row.progress or {}).get("history") else None,
            "updated_at": row.updated_at.isoformat() if row.updated_at else None,
        }
    progress = job["progress"] or {}
    version = (job["status"], progress.get("generation"), len(progress.get("history") or []), job["updated_at"])
    content, hit = figures.cached(("job", job_id, name, format, version), lambda: figures.render_job_figure(job, format))
    return image_response(request, content, format, hit, immutable=False)
