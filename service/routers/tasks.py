"""Task presets (the paper's detection line and variants)."""

from __future__ import annotations

from fastapi import APIRouter

from service.errors import NotFoundError, responses
from service.schemas import PAPER_TASK_EXAMPLE, TaskIn, TaskPreset, TaskPresetList

router = APIRouter(prefix="/v1/task-presets", tags=["tasks"])

PRESETS: dict[str, TaskPreset] = {
    "paper-line": TaskPreset(
        name="paper-line",
        description="The paper's detection line on the Table-1 robot: 15 s, trapezoidal, dt 0.25 s, 6 deg/s limit",
        robot_id="table1",
        task=TaskIn(**PAPER_TASK_EXAMPLE),
    ),
    "paper-line-quintic": TaskPreset(
        name="paper-line-quintic",
        description="The paper's detection line with a quintic time profile",
        robot_id="table1",
        task=TaskIn(**{**PAPER_TASK_EXAMPLE, "profile": "quintic"}),
    ),
    "paper-line-fine": TaskPreset(
        name="paper-line-fine",
        description="The paper's detection line with dt 0.05 s",
        robot_id="table1",
        task=TaskIn(**{**PAPER_TASK_EXAMPLE, "dt_s": 0.05}),
    ),
}


@router.get("", operation_id="list_task_presets", response_model=TaskPresetList, summary="List task presets")
def list_task_presets() -> TaskPresetList:
    return TaskPresetList(items=list(PRESETS.values()), total=len(PRESETS))


@router.get(
    "/{name}", operation_id="get_task_preset", response_model=TaskPreset, summary="Get a task preset", responses=responses(404)
)
def get_task_preset(name: str) -> TaskPreset:
    if name not in PRESETS:
        raise NotFoundError("task preset", name)
    return PRESETS[name]
