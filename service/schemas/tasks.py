"""Cartesian tasks (their paths: :mod:`service.schemas.paths`) and task presets."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Annotated, Self

import numpy as np
from pydantic import ConfigDict, Field, model_validator

from engine import CartesianTask, RobotModel
from engine.bounds import MAX_LENGTH_M
from engine.errors import ParameterError
from engine.trajectory import MAX_DURATION_S, MIN_DT_S, start_pose
from service.schemas.common import (
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    EngineName,
    Input,
    JointLengths,
    JointValues,
    Output,
    Quaternion,
    TimeProfile,
    TrackedQuantity,
    Vec3,
    field_path,
    joint_positions,
)
from service.schemas.geometry import SceneIn
from service.schemas.methods import MethodIn
from service.schemas.paths import LinePathIn, PathContext, PathIn, rotation


class TaskIn(Input):
    """A Cartesian task: the end effector follows `path` (by default the straight line to the
    target pose) from the forward kinematics of ``q0_deg`` with the base at rest at the origin.
    Errors in path fields are reported at ``task.path.<type>.<field>``."""

    model_config = ConfigDict(json_schema_extra={"examples": [PAPER_TASK_EXAMPLE]}, allow_inf_nan=False)

    q0_deg: JointValues | None = Field(
        default=None, description="initial joint angles of the revolute joints, deg (null at prismatic joints)"
    )
    q0_m: JointLengths | None = Field(
        default=None, description="initial positions of the prismatic joints, m (null at revolute joints)"
    )
    tracks: TrackedQuantity = Field(
        default="pose",
        description="what the plan follows: the whole `pose` (needs 6 joints or more) or the `position` only (3 or more)",
    )
    target_position_m: Vec3 | None = Field(
        default=None, description="target end-effector position, m (line paths only, required)"
    )
    target_attitude_quaternion: Quaternion | None = Field(
        default=None,
        description="target end-effector attitude [w, x, y, z] (line paths only, normalised; required for pose tasks, "
        "position tasks keep the start one)",
    )
    duration_s: float | None = Field(
        default=None,
        gt=0,
        le=MAX_DURATION_S,
        description="s; line and arc: default 15; waypoints and raster: default the path's own timing, else rescaled to it",
    )
    ramp_time_s: float = Field(default=1.5, ge=0, le=300, description="s, trapezoidal profile only; at most duration_s / 2")
    dt_s: float = Field(
        default=0.25,
        ge=MIN_DT_S,
        le=1,
        description="planner step, s: at most the path's duration; duration_s / dt_s at most 20,000 steps. The last "
        "sample is the first multiple of dt_s at or after the duration (the path held at its end after it)",
    )
    profile: TimeProfile = Field(default="trapezoidal", description="time law of line and arc paths")
    joint_speed_limit_deg_s: float = Field(
        default=6.0, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the revolute joints, deg/s"
    )
    joint_speed_limit_m_s: Annotated[float | None, EngineName("linear_joint_speed_limit")] = Field(
        default=None, gt=0, le=MAX_MAGNITUDE, description="symmetric speed limit of the prismatic joints, m/s (null: none)"
    )
    path: PathIn = Field(default_factory=LinePathIn, description="the path type and its parameters (default: line)")
    clearance_m: float = Field(
        default=0.0,
        ge=0,
        le=MAX_LENGTH_M,
        description="the smallest distance allowed between any two shapes that are checked (each link and each "
        "obstacle, each link and the carrier but link 1, links at least two apart, the carrier and each obstacle), m; "
        "a plan that comes closer fails, and P_l of B counts it. Checked when the robot has collision shapes",
    )
    scene: SceneIn | None = Field(default=None, description="obstacles and avoidance settings (null: no obstacles)")

    @model_validator(mode="after")
    def _default_duration(self) -> Self:
        """A line's or an arc's duration left out is its default, 15 s, filled in where it is read
        (so a stored request says what was planned); other paths keep null: their own timing."""
        if self.duration_s is None and self.path.default_duration_s is not None:
            self.duration_s = self.path.default_duration_s
        return self

    def to_engine(self, model: RobotModel) -> CartesianTask:
        """The engine's task for ``model``; errors name the engine's fields (:meth:`locate` finds them)."""
        q0 = joint_positions(model, self.q0_deg, self.q0_m, ("q0_deg", "q0_m"))
        position, attitude = start_pose(model, q0)
        context = PathContext(
            duration=self.duration_s,
            ramp_time=self.ramp_time_s,
            profile=self.profile,
            target_position=None if self.target_position_m is None else np.asarray(self.target_position_m, dtype=float),
            target_attitude=None
            if self.target_attitude_quaternion is None
            else rotation(self.target_attitude_quaternion, "target_attitude"),
            tracks=self.tracks,
        )
        try:
            scene = (self.scene or SceneIn()).to_engine(self.clearance_m)
        except ParameterError as exc:
            raise (exc if exc.field == "clearance" else exc.within("scene")) from None
        return CartesianTask(
            q0=q0,
            path=self.path.to_engine(position, attitude, context),
            dt=self.dt_s,
            joint_speed_limit=math.radians(self.joint_speed_limit_deg_s),
            tracks=self.tracks,
            linear_joint_speed_limit=math.inf if self.joint_speed_limit_m_s is None else self.joint_speed_limit_m_s,
            scene=scene,
        )

    def locate(self, field: str | Sequence[str | int]) -> list[str | int]:
        """As :meth:`Input.locate`; a joint of ``q0`` is in the list of its unit, and what the task
        does not have is its path's (``path.<type>.<field>``)."""
        parts = field_path(field) if isinstance(field, str) else list(field)
        head = parts[0] if parts else None
        if head == "q0" and len(parts) == 2 and isinstance(parts[1], int):
            j = parts[1]
            prismatic = self.q0_m is not None and j < len(self.q0_m) and self.q0_m[j] is not None
            return ["q0_m" if prismatic else "q0_deg", j]
        if head == "path" or (isinstance(head, str) and head not in self.engine_fields()):
            rest = parts[1:] if head == "path" else parts
            return ["path", self.path.kind, *self.path.locate(rest)]
        return super().locate(parts)

    def path_timing(self, task: CartesianTask) -> dict[str, float]:
        """The fields of this task that describe ``task``'s (retimed) path: its duration and, for
        the paths on one time law, the ramp time."""
        return {"duration_s": task.duration, **self.path.timing(task.path)}


class TaskPreset(Output):
    """A named task, in the shape of the request fields it fills (`robot_id`, `task`, `method` of
    a plan request)."""

    name: str = Field(description="the preset's name (its id)")
    description: str = Field(description="what the task is, for a person")
    robot_id: str = Field(description="the stored robot the task is meant for")
    task: TaskIn = Field(description="the task, ready to post")
    method: MethodIn | None = Field(
        default=None, description="the method and parameters the preset is meant to be planned with (every preset has one)"
    )


class TaskPresetList(Output):
    items: list[TaskPreset] = Field(description="every task preset")
    total: int = Field(description="number of task presets")
