"""Objective landscapes: B over a grid of two parameters of a method."""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import (
    ConfigDict,
    Field,
)
from typing_extensions import TypeAliasType

from engine import PlanOptions, axis_values
from engine.inverses import REGISTRY
from service.schemas.common import (
    MAX_MAGNITUDE,
    PAPER_TASK_EXAMPLE,
    Input,
    Magnitude,
    Output,
    field_path,
    vocabulary,
)
from service.schemas.methods import PARAM_NAMES, MethodParams
from service.schemas.robots import OneRobot
from service.schemas.tasks import TaskIn
from service.schemas.tuning import ObjectiveSettings

# --- objective landscapes

#: Methods with (at least) two parameters to span a landscape.
if TYPE_CHECKING:
    LandscapeMethod = str
    ParamName = str
else:
    LandscapeMethod = vocabulary("LandscapeMethod", [m.name for m in REGISTRY if len(m.params) >= 2])
    ParamName = vocabulary("ParamName", PARAM_NAMES)
AxisScale = TypeAliasType("AxisScale", Literal["linear", "log"])


class LandscapeAxis(Input):
    """One axis of the grid: a parameter of the method and its values."""

    name: ParamName = Field(description="a parameter of the method, e.g. `lambda_max` or `epsilon` (see `MethodParams`)")
    min: Magnitude = Field(description="first value, in the parameter's unit (see `MethodParams`); > 0 on a log axis")
    max: Magnitude = Field(description="last value, in the parameter's unit (> min)")
    steps: int = Field(default=32, ge=2, le=128, description="values from min to max inclusive")
    scale: AxisScale = Field(default="linear", description="spacing of the values: `linear` or `log` (even in the logarithm)")

    def values(self) -> np.ndarray:
        """The axis's values (errors name ``min``, ``max``, ``steps``)."""
        return axis_values(self.min, self.max, self.steps, self.scale)


class LandscapeRequest(OneRobot):
    model_config = ConfigDict(
        allow_inf_nan=False,
        json_schema_extra={
            "examples": [
                {
                    "robot_id": "table1",
                    "tasks": [PAPER_TASK_EXAMPLE],
                    "method": "adaptive",
                    "x": {"name": "lambda_max", "min": 0.001, "max": 0.2, "steps": 64},
                    "y": {"name": "epsilon", "min": 0.001, "max": 1.0, "steps": 64},
                }
            ]
        },
    )

    tasks: list[TaskIn] = Field(min_length=1, max_length=8, description="B is their mean (or max, see objective)")
    method: LandscapeMethod = Field(default="adaptive", description="a method with two parameters or more")
    x: LandscapeAxis = Field(description="the parameter along the grid's rows (first index)")
    y: LandscapeAxis = Field(description="the parameter along the grid's columns (second index)")
    fixed: MethodParams | None = Field(
        default=None, description="the method's other parameters (default: their defaults); not those of the axes"
    )
    objective: ObjectiveSettings = Field(default_factory=ObjectiveSettings, description="the objective B")
    feedback_gain: float = Field(default=0.0, ge=0, le=MAX_MAGNITUDE, description="1/s, pose-error feedback")
    tuning_job_id: str = Field(  # type: ignore[assignment]
        default=None,
        pattern=r"^[0-9a-f]{32}$",
        description="a succeeded tuning job of the same method: its GA optimum is marked on the heatmap and "
        "its tuned DLS objective drawn as a contour (where the method beats the tuned DLS)",
    )

    def options(self) -> PlanOptions:
        return PlanOptions(feedback_gain=self.feedback_gain, objective=self.objective.to_engine())

    def locate(self, field: str | Sequence[str | int]) -> list[str | int]:
        """As :meth:`Input.locate`; the engine's ``x`` or ``y`` (the values of an axis) are the axis's ``min``."""
        parts = field_path(field) if isinstance(field, str) else list(field)
        if parts in (["x"], ["y"]):
            return [parts[0], "min"]
        return super().locate(parts)


class LandscapeAxisOut(Output):
    name: ParamName = Field(description="the parameter along this axis")
    values: list[float] = Field(description="the parameter's values along this axis, in its unit (see `MethodParams`)")
    scale: AxisScale = Field(description="spacing of the values")


class LandscapeMarks(Output):
    tuning_job_id: str = Field(description="the tuning job marked on the heatmap")
    ga_optimum: MethodParams = Field(description="the job's tuned parameters")
    ga_objective_b: float | None = Field(description="the job's tuned B")
    dls_objective_b: float | None = Field(description="B of the job's tuned DLS baseline (null without one)")


class LandscapeLinks(Output):
    model_config = ConfigDict(populate_by_name=True)

    self_: str = Field(alias="self", description="this landscape")
    heatmap: str = Field(description="its heatmap figure, SVG; `?format=png` for PNG")


class LandscapeOut(Output):
    id: str = Field(description="the landscape's id (32 hex digits)")
    robot_id: str | None = Field(description="the stored robot; null for an inline robot")
    method: LandscapeMethod = Field(description="the method whose parameters span the grid")
    x: LandscapeAxisOut = Field(description="the grid's rows (first index)")
    y: LandscapeAxisOut = Field(description="the grid's columns (second index)")
    fixed: MethodParams = Field(description="the method's other parameters")
    objective_b: list[list[float | None]] = Field(description="B per cell [x index][y index]; null where infeasible")
    feasible: list[list[bool]] = Field(description="every task's plan finite and within the joint speed limit")
    max_joint_speed_deg_s: list[list[float | None]] = Field(
        description="the largest joint speed over the tasks, deg/s (null where a plan diverged)"
    )
    best_params: MethodParams = Field(description="the cell with the smallest B (empty if none is feasible)")
    best_objective_b: float | None = Field(description="B of that cell; null if none is feasible")
    feasible_fraction: float = Field(description="share of feasible cells, 0 to 1")
    marks: LandscapeMarks | None = Field(description="the tuning job named in the request; null if none")
    evaluations: int = Field(description="plans run: cells x tasks")
    elapsed_s: float = Field(description="s, computing the grid")
    created_at: datetime = Field(description="when it was stored (UTC)")
    links: LandscapeLinks = Field(description="where its heatmap is")
