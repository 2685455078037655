"""Task presets (the paper's detection line and variants, and lines for the URDF example robots)."""

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
    "arm7-line": TaskPreset(
        name="arm7-line",
        description="The 7-joint arm on its spacecraft (URDF example): a 0.37 m line with a 20 deg turn in 20 s, "
        "6 deg/s limit; plan it with and without the secondary objective min_base_rotation",
        robot_id="arm7",
        task=TaskIn(
            q0_deg=[0.0, 40.0, 0.0, 80.0, 0.0, 50.0, 0.0],
            target_position_m=[0.8878, 0.3099, -0.5009],
            target_attitude_quaternion=[0.482759, -0.411213, -0.51896, 0.573173],
            duration_s=20.0,
            ramp_time_s=2.0,
            dt_s=0.25,
            joint_speed_limit_deg_s=6.0,
        ),
    ),
    "arm3-position": TaskPreset(
        name="arm3-position",
        description="The 3-joint arm (yaw, pitch, telescopic boom; URDF example) moves its tool 0.33 m in 20 s, "
        "tracking the position only; 6 deg/s and 0.05 m/s limits",
        robot_id="arm3",
        task=TaskIn(
            q0_deg=[0.0, 20.0, None],
            q0_m=[None, None, 0.2],
            tracks="position",
            target_position_m=[1.5156, 0.3, 1.2288],
            duration_s=20.0,
            ramp_time_s=2.0,
            dt_s=0.25,
            joint_speed_limit_deg_s=6.0,
            joint_speed_limit_m_s=0.05,
        ),
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
