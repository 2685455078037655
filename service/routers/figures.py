"""Figures of plans and tuning jobs (SVG, PNG at a chosen ``dpi``, or PDF; rendered by :mod:`service.figures`).

Plan and job ids are matched as 32 hex digits (``{plan_id:id}``), so
``/v1/plans/compare/figures/tracking-errors`` is never read as the figure of a plan ``compare``."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from service import figures
from service.deps import (
    IMAGE_RESPONSES,
    Dpi,
    Format,
    JobId,
    PlanId,
    SessionRoute,
    UnknownFigureError,
    figure_dpi,
    figure_name,
    image_response,
)
from service.errors import responses
from service.usecases import figures as figure_cases

router = APIRouter(tags=["figures"], route_class=SessionRoute)


@router.get(
    "/v1/plans/compare/figures/{name}",
    operation_id="compare_plans_figure",
    summary="Several plans on one figure (e.g. DLS versus GA-tuned adaptive damping, the paper's Fig. 9)",
    description="`ids` is a comma-separated list of plan ids (at most 8). Every plan figure compares: the plans side by "
    "side, one column each (titled by its method and id) on shared y axes; `tracking-errors` overlays the plans' error "
    "norms on one pair of axes. Names: " + ", ".join(f"`{n}`" for n in figures.COMPARE_FIGURES),
    response_class=Response,
    responses={**IMAGE_RESPONSES, **responses(404, 422)},
)
async def compare_plans_figure(
    name: Annotated[str, figure_name(figures.COMPARE_FIGURES)],
    request: Request,
    ids: Annotated[str, Query(description="comma-separated plan ids", min_length=1, max_length=2000)],
    format: Format = "svg",
    dpi: Dpi = None,
) -> Response:
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_compare_plans_figure, name, request, ids, format, figure_dpi(format, dpi))
        return response


def _compare_plans_figure(name: str, request: Request, ids: str, format: str, dpi: int | None) -> Response:
    if name not in figures.COMPARE_FIGURES:
        raise UnknownFigureError(name, figures.COMPARE_FIGURES)
    content, hit = figure_cases.compare_figure(request.app.state.db, name, ids, format, dpi)
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
    plan_id: PlanId,
    name: Annotated[str, figure_name(list(figures.PLAN_FIGURES))],
    request: Request,
    format: Format = "svg",
    dpi: Dpi = None,
) -> Response:
    if name not in figures.PLAN_FIGURES:
        raise UnknownFigureError(name, list(figures.PLAN_FIGURES))
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_plan_figure, plan_id, name, request, format, figure_dpi(format, dpi))
        return response


def _plan_figure(plan_id: PlanId, name: str, request: Request, format: str, dpi: int | None) -> Response:
    content, hit = figure_cases.plan_figure(request.app.state.db, plan_id, name, format, dpi)
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
    job_id: JobId,
    name: Annotated[str, figure_name(figures.JOB_FIGURES)],
    request: Request,
    format: Format = "svg",
    dpi: Dpi = None,
) -> Response:
    if name not in figures.JOB_FIGURES:
        raise UnknownFigureError(name, figures.JOB_FIGURES)
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_job_figure, job_id, name, request, format, figure_dpi(format, dpi))
        return response


def _job_figure(job_id: JobId, name: str, request: Request, format: str, dpi: int | None) -> Response:
    content, hit = figure_cases.job_figure(request.app.state.db, job_id, name, format, dpi)
    return image_response(request, content, format, hit, immutable=False)
