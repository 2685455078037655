"""Task presets (:mod:`service.usecases.presets`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path

from service.deps import SessionRoute
from service.errors import responses
from service.schemas.tasks import TaskPreset, TaskPresetList
from service.usecases import presets

router = APIRouter(prefix="/v1/task-presets", tags=["tasks"], route_class=SessionRoute)


@router.get(
    "",
    operation_id="list_task_presets",
    response_model=TaskPresetList,
    summary="List task presets",
    description="Every task preset: the paper's detection line (`paper-line`) and its variants, a raster scan and a "
    "waypoint inspection, each with the robot and method it is meant for, in the shape of a plan request's fields.",
)
def list_task_presets() -> TaskPresetList:
    return presets.listing()


@router.get(
    "/{name}",
    operation_id="get_task_preset",
    response_model=TaskPreset,
    summary="Get a task preset",
    description="One task preset by name; its `task` (and `method`, if any) can be posted as they are in a plan "
    "request or (the task) a tuning job.",
    responses=responses(404),
)
def get_task_preset(name: Annotated[str, Path(description="the preset's name, e.g. `paper-line`")]) -> TaskPreset:
    return presets.get(name)
