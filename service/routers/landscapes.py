"""Objective landscapes (synchronous, bounded, stored): ``B``, feasibility and peak joint speed
over a grid of two parameters of a method (:func:`engine.landscape`), with a heatmap figure.
Computed behind the plan admission, like plans."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from service.deps import (
    IMAGE_RESPONSES,
    DbDep,
    Dpi,
    Format,
    JsonAnswer,
    JsonBody,
    LandscapeId,
    SessionDep,
    SessionRoute,
    SettingsDep,
    figure_dpi,
    image_response,
    run_admitted,
)
from service.errors import responses
from service.infra.db import Database
from service.schemas.landscapes import LandscapeOut, LandscapeRequest
from service.usecases import landscapes
from service.usecases.landscapes import MAX_LANDSCAPE_JOINT_STEPS

router = APIRouter(prefix="/v1/landscapes", tags=["landscapes"], route_class=SessionRoute)


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
    responses=responses(404, 406, 415, 422),
    dependencies=[JsonAnswer, JsonBody],
)
async def create_landscape(body: LandscapeRequest, request: Request, settings: SettingsDep) -> Response:
    db: Database = request.app.state.db

    def work() -> Response:
        landscape_id, content = landscapes.create(db, settings, body)
        headers = {"Location": f"/v1/landscapes/{landscape_id}"}
        return Response(content, status_code=201, media_type="application/json", headers=headers)

    return await run_admitted(request, work)


@router.get(
    "/{landscape_id:id}",
    operation_id="get_landscape",
    response_model=LandscapeOut,
    summary="Get a stored objective landscape",
    description="The grid as computed (B per cell [x index][y index], null where infeasible).",
    responses=responses(404),
)
def get_landscape(landscape_id: LandscapeId, session: SessionDep) -> Response:
    return Response(landscapes.read(session, landscape_id), media_type="application/json")


@router.delete(
    "/{landscape_id:id}",
    operation_id="delete_landscape",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a stored objective landscape",
    description="204 once deleted; 404 for an unknown id.",
    responses=responses(404),
)
def delete_landscape(landscape_id: LandscapeId, db: DbDep) -> Response:
    landscapes.delete(db, landscape_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


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
async def get_landscape_heatmap(landscape_id: LandscapeId, request: Request, format: Format = "svg", dpi: Dpi = None) -> Response:
    async with request.app.state.figure_admission.slot():
        response: Response = await run_in_threadpool(_heatmap, request, landscape_id, format, figure_dpi(format, dpi))
        return response


def _heatmap(request: Request, landscape_id: str, format: str, dpi: int | None) -> Response:
    content, hit = landscapes.heatmap(request.app.state.db, landscape_id, format, dpi)
    return image_response(request, content, format, hit, immutable=True)
