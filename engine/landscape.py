"""Objective landscapes: ``B`` over a grid of two parameters of an inverse, on one or more tasks.

Every cell is one metrics-only plan per task on the compiled kernels (:func:`engine.planner.
evaluate`, spread over threads), so a 64 x 64 grid of the paper's task takes about a second. The
landscape shows what the GA searches: where the damping is feasible (joint speeds within the
limit, the plan finite), how flat ``B`` is, and where its minimum lies.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from engine.errors import ParameterError
from engine.inverses import method_spec
from engine.model import RobotModel
from engine.planner import PlanOptions, PlanSetup, Stop, evaluate
from engine.spatial import FloatArray
from engine.trajectory import CartesianTask
from engine.tuning import TASK_AGGREGATIONS

MAX_STEPS_PER_AXIS = 128


@dataclass(frozen=True)
class Landscape:
    """``B`` and feasibility on the grid ``x_values`` (rows) x ``y_values`` (columns)."""

    method: str
    x_name: str
    y_name: str
    x_values: FloatArray  # (nx,)
    y_values: FloatArray  # (ny,)
    fixed: dict[str, float]  # the method's other parameters
    objective_b: FloatArray  # (nx, ny), over the tasks (mean or max); inf where infeasible
    feasible: np.ndarray  # (nx, ny) bool: every task's plan finite and within the joint speed limit
    max_joint_speed: FloatArray  # (nx, ny) rad/s, the largest over the tasks (nan where a plan diverged)
    best_params: dict[str, float]  # the cell with the smallest B (empty if none is feasible)
    best_objective_b: float
    evaluations: int  # plans run (cells x tasks)
    elapsed_s: float


def axis_values(low: float, high: float, steps: int, scale: str = "linear") -> FloatArray:
    """``steps`` values from ``low`` to ``high`` inclusive, evenly spaced (``linear``) or evenly
    spaced in their logarithm (``log``, both ends > 0)."""
    if not 2 <= steps <= MAX_STEPS_PER_AXIS:
        raise ParameterError("steps", f"must be in [2, {MAX_STEPS_PER_AXIS}]")
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise ParameterError("max", f"expected finite min < max, got [{low}, {high}]")
    if scale == "log":
        if low <= 0.0:
            raise ParameterError("min", "a log axis needs min > 0")
        return np.geomspace(low, high, steps)
    if scale != "linear":
        raise ParameterError("scale", "must be linear or log")
    return np.linspace(low, high, steps)


def landscape(
    model: RobotModel,
    tasks: CartesianTask | Sequence[CartesianTask],
    method: str,
    x: tuple[str, Sequence[float] | FloatArray],
    y: tuple[str, Sequence[float] | FloatArray],
    *,
    fixed: Mapping[str, float] | None = None,
    options: PlanOptions | None = None,
    task_aggregation: str = "mean",
    threads: int | None = None,
    stop: Stop | None = None,
    **option_fields: Any,
) -> Landscape:
    """Plan every ``(x, y)`` cell of ``method``'s parameters ``x = (name, values)`` and
    ``y = (name, values)`` (``fixed`` gives the method's other parameters, default: their
    defaults) on each task, with ``options`` (or their keywords, see :meth:`PlanOptions.of`);
    ``B`` is formed as in :func:`engine.tuning.tune` (the tasks' mean or max,
    ``task_aggregation``). Raises :class:`ParameterError` naming the bad argument."""
    task_list = (tasks,) if isinstance(tasks, CartesianTask) else tuple(tasks)
    if not task_list:
        raise ParameterError("tasks", "at least one task is needed")
    spec = method_spec(method)
    known = {p.name: p for p in spec.params}
    if len(known) < 2:
        raise ParameterError("method", f"{method} has {len(known)} parameter(s); a landscape needs two")
    (x_name, x_raw), (y_name, y_raw) = x, y
    for field, name in (("x.name", x_name), ("y.name", y_name)):
        if name not in known:
            raise ParameterError(field, f"unknown parameter {name!r} of {method}; valid: {', '.join(known)}")
    if x_name == y_name:
        raise ParameterError("y.name", "must differ from x.name")
    x_values = known[x_name].check(np.asarray(x_raw, dtype=float), "x")
    y_values = known[y_name].check(np.asarray(y_raw, dtype=float), "y")
    others = {name: p for name, p in known.items() if name not in (x_name, y_name)}
    unknown = set(fixed or {}) - set(others)
    if unknown:
        further = f"these are: {', '.join(others)}" if others else f"{method} has none besides {x_name} and {y_name}"
        raise ParameterError(f"fixed.{min(unknown)}", f"not a further parameter of {method} (the axes' are not); {further}")
    fixed_values = {name: float((fixed or {}).get(name, p.default)) for name, p in others.items()}
    for name, value in fixed_values.items():
        others[name].check(np.array([value]), f"fixed.{name}")
    if task_aggregation not in TASK_AGGREGATIONS:
        raise ParameterError("task_aggregation", f"must be one of {', '.join(TASK_AGGREGATIONS)}")
    setups = PlanSetup.of_tasks(model, task_list, options or PlanOptions.of(**option_fields))

    start = time.perf_counter()
    grid_x, grid_y = np.meshgrid(x_values, y_values, indexing="ij")
    cells = grid_x.size
    columns = {x_name: grid_x.ravel(), y_name: grid_y.ravel(), **{n: np.full(cells, v) for n, v in fixed_values.items()}}
    inverse = spec(**columns)
    per_task_b = np.empty((len(task_list), cells))
    speed = np.full(cells, -np.inf)
    feasible = np.ones(cells, dtype=bool)
    for k, setup in enumerate(setups):
        metrics = setup.metrics(evaluate(setup, inverse, cells, threads=threads, stop=stop))
        per_task_b[k] = metrics.objective_b
        feasible &= np.isfinite(metrics.objective_b)
        speed = np.fmax(speed, np.where(metrics.finite, metrics.max_joint_speed, np.nan))
    b = per_task_b.mean(axis=0) if task_aggregation == "mean" else per_task_b.max(axis=0)
    b = np.where(feasible, b, np.inf)
    best: dict[str, float] = {}
    best_b = math.inf
    if feasible.any():
        i = int(np.argmin(b))
        best = {name: float(values[i]) for name, values in columns.items()}
        best_b = float(b[i])
    shape = grid_x.shape
    return Landscape(
        method=method,
        x_name=x_name,
        y_name=y_name,
        x_values=x_values,
        y_values=y_values,
        fixed=fixed_values,
        objective_b=b.reshape(shape),
        feasible=feasible.reshape(shape),
        max_joint_speed=np.where(np.isfinite(speed), speed, np.nan).reshape(shape),
        best_params=best,
        best_objective_b=best_b,
        evaluations=cells * len(task_list),
        elapsed_s=time.perf_counter() - start,
    )
