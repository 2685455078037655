"""The shortest feasible duration of a task: the smallest time scale of its path at which a
method's plan succeeds (finite, within the joint speed limit, on the path and at the target
within the tolerances; :func:`engine.planner.plan`'s verdict).

The path is retimed uniformly (:meth:`CartesianTask.with_duration`: same geometry, every speed
scaled) and the duration searched by bisection, several candidate durations per round planned
at once (metrics only, over the thread pool: :func:`engine.planner.evaluate_tasks`). Each round
keeps the bracket ``(lo, hi]`` between the longest infeasible duration below the shortest
feasible one ``hi``; ``K`` candidates spaced geometrically inside it shrink its log-width by
``K + 1`` per round, until ``hi / lo - 1 <= relative_tolerance``. Before both ends are known
the candidates step by factors of two from the given duration. The search assumes that
feasibility is monotone in the duration near the boundary (a faster path needs faster joints);
where it is not, ``hi`` is still feasible and ``lo`` still infeasible, but other boundaries may
exist. The result carries the plan at ``hi``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from engine.errors import ParameterError
from engine.inverses import Inverse
from engine.planner import PlanResult, PlanSetup, evaluate_setups, run_plan, verdicts
from engine.trajectory import MAX_DURATION_S, MAX_STEPS

DEFAULT_RELATIVE_TOLERANCE = 0.002
MAX_CANDIDATES = 64
MAX_ROUNDS = 60


@dataclass(frozen=True)
class DurationSearch:
    """Result of :func:`shortest_duration`. Durations in s, the margin in rad/s."""

    duration: float  # shortest feasible duration found (the plan's); the longest tried if none
    infeasible_duration: float  # longest infeasible duration below it; nan if none was
    relative_gap: float  # duration / infeasible_duration - 1 (the bracket's width); nan without one
    speed_margin: float  # joint speed limit minus the plan's peak joint speed
    limiting: str  # the verdict at infeasible_duration: what breaks when faster ("" without one)
    plan: PlanResult
    evaluations: int  # metrics-only plans run (the returned full plan not counted)
    rounds: int
    success: bool
    message: str


def shortest_duration(
    setup: PlanSetup,
    inverse: Inverse,
    *,
    relative_tolerance: float = DEFAULT_RELATIVE_TOLERANCE,
    candidates: int = 4,
    max_duration: float | None = None,
    threads: int | None = None,
) -> DurationSearch:
    """The shortest duration of the setup's task path (s) at which ``inverse`` plans it
    successfully, to ``relative_tolerance``, searched between one step (``task.dt``) and
    ``max_duration`` (default and at most the task limits: 600 s and 20,000 steps); ``candidates``
    durations are planned per round. ``success`` is false (with the plan at the longest duration
    tried) when no duration up to the maximum is feasible."""
    task = setup.task
    if not (math.isfinite(relative_tolerance) and 0.0 < relative_tolerance <= 0.1):
        raise ParameterError("relative_tolerance", "must be in (0, 0.1]")
    if not 1 <= candidates <= MAX_CANDIDATES:
        raise ParameterError("candidates", f"must be in [1, {MAX_CANDIDATES}]")
    lowest = task.dt
    highest = min(MAX_DURATION_S, MAX_STEPS * task.dt)
    if max_duration is not None:
        if not (math.isfinite(max_duration) and max_duration >= lowest):
            raise ParameterError("max_duration", f"must be at least one step ({lowest:g} s)")
        highest = min(highest, float(max_duration))
    start = min(max(task.duration, lowest), highest)

    feasible: dict[float, bool] = {}
    verdict_of: dict[float, str] = {}
    evaluations = 0
    rounds = 0

    def run(durations: list[float]) -> None:
        nonlocal evaluations
        fresh = sorted({min(max(d, lowest), highest) for d in durations} - set(feasible))
        if not fresh:
            return
        setups = [setup.retimed(d) for d in fresh]
        raw = evaluate_setups(setups, inverse, threads=threads)
        for d, (_, ok, message) in zip(fresh, verdicts(raw, setups), strict=True):
            feasible[d] = ok
            verdict_of[d] = message
        evaluations += len(fresh)

    def bracket() -> tuple[float | None, float | None]:
        good = [d for d, ok in feasible.items() if ok]
        hi = min(good) if good else None
        bad = [d for d, ok in feasible.items() if not ok and (hi is None or d < hi)]
        return (max(bad) if bad else None), hi

    half = candidates // 2
    run([start * 2.0 ** (i - half) for i in range(candidates)])
    rounds = 1
    while rounds < MAX_ROUNDS:
        lo, hi = bracket()
        if hi is None:
            top = max(feasible)
            if top >= highest:
                break
            run([top * 2.0 ** (i + 1) for i in range(candidates)])
        elif lo is None:
            if hi <= lowest:
                break
            run([hi * 2.0 ** -(i + 1) for i in range(candidates)])
        else:
            if hi / lo - 1.0 <= relative_tolerance:
                break
            ratio = hi / lo
            run([lo * ratio ** (j / (candidates + 1)) for j in range(1, candidates + 1)])
        rounds += 1

    lo, hi = bracket()

    def full_plan(duration: float) -> PlanResult:
        return run_plan(setup.retimed(duration), inverse)

    if hi is None:
        top = max(feasible)
        result = full_plan(top)
        return DurationSearch(
            duration=top,
            infeasible_duration=top,
            relative_gap=math.nan,
            speed_margin=result.task.joint_speed_limit - result.metrics.max_joint_speed,
            limiting=verdict_of[top],
            plan=result,
            evaluations=evaluations,
            rounds=rounds,
            success=False,
            message=f"no feasible duration up to {top:g} s: {verdict_of[top]}",
        )
    result = full_plan(hi)
    margin = result.task.joint_speed_limit - result.metrics.max_joint_speed
    if lo is None:
        message = f"feasible down to one step ({hi:g} s), the shortest duration tried"
        gap, limiting = math.nan, ""
    else:
        gap, limiting = hi / lo - 1.0, verdict_of[lo]
        message = f"shortest feasible duration {hi:.6g} s (infeasible at {lo:.6g} s: {limiting})"
    if not result.success:  # cannot happen: the same kernel gave the metrics
        message = f"{message}; but the full plan failed: {result.message}"
    return DurationSearch(
        duration=hi,
        infeasible_duration=math.nan if lo is None else lo,
        relative_gap=gap,
        speed_margin=margin,
        limiting=limiting,
        plan=result,
        evaluations=evaluations,
        rounds=rounds,
        success=result.success,
        message=message,
    )
