"""GA tuning of an inverse's parameters (paper sections 3.2 and 4), split as pymoo splits an
optimisation: the problem (:class:`TuningProblem`, a population evaluated at a time on the
compiled kernels), the algorithm (:class:`BinaryGA`, the paper's binary GA with ask/tell, DEAP
inside) and one termination (:class:`Termination`: generations, cancellation, deadline).
:func:`tune` and :func:`compare` drive them; the service's worker drives them itself, one
generation at a time (:mod:`service.usecases.tuning_run`)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from engine.errors import ParameterError
from engine.inverses import method_spec
from engine.metrics import Metrics
from engine.model import RobotModel
from engine.planner import EvaluationStoppedError, PlanOptions
from engine.trajectory import CartesianTask
from engine.tuning.ga import (
    INFEASIBLE_FITNESS,
    MAX_BITS_PER_GENE,
    MAX_GENERATIONS,
    MAX_POPULATION,
    BinaryGA,
    GASettings,
    GenerationRecord,
    decode,
)
from engine.tuning.problem import (
    ROBUST_STATISTICS,
    TASK_AGGREGATIONS,
    Chunk,
    MapFn,
    Robust,
    TuningProblem,
    check_bounds,
    dask_map,
    evaluate_chunk,
)
from engine.tuning.refine import Refinement, starting_points
from engine.tuning.refine import refine as refine_best
from engine.tuning.termination import Termination
from engine.uncertainty import Uncertainty

__all__ = [
    "INFEASIBLE_FITNESS",
    "MAX_BITS_PER_GENE",
    "MAX_GENERATIONS",
    "MAX_POPULATION",
    "ROBUST_STATISTICS",
    "TASK_AGGREGATIONS",
    "BinaryGA",
    "Chunk",
    "Comparison",
    "GASettings",
    "GenerationRecord",
    "MapFn",
    "Refinement",
    "Robust",
    "Termination",
    "TuneProgress",
    "TuneResult",
    "TuningProblem",
    "bound_warnings",
    "check_bounds",
    "compare",
    "dask_map",
    "decode",
    "evaluate_chunk",
    "improvement_percent",
    "run",
    "tune",
]


@dataclass(frozen=True)
class TuneProgress:
    """Reported to the callback after every generation (generation 0 is the initial one)."""

    generation: int
    generations: int
    evaluations: int  # plans run so far (repeated genomes are not planned again)
    best_objective_b: float  # best so far; inf if nothing feasible yet
    mean_objective_b: float  # mean over this generation's feasible individuals; inf if none
    feasible: int  # feasible individuals in this generation
    best_params: dict[str, float]
    phase: str = "ga"  # "ga", or "refine" (a round of the pattern search after the GA)


@dataclass(frozen=True)
class TuneResult:
    method: str
    best_params: dict[str, float]
    best_objective_b: float
    best_metrics: list[Metrics]  # metrics of the best parameters, one per task
    history: list[GenerationRecord]
    evaluations: int  # plans run (distinct genomes x tasks)
    elapsed_s: float
    seed: int | None
    success: bool
    message: str
    stopped: bool = False
    bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    cache_hits: int = 0  # individuals whose genome had been planned before (not planned again)
    warnings: list[str] = field(default_factory=list)  # e.g. an optimum on a search bound
    ga_objective_b: float = math.inf  # the GA's own best B, before the refinement (= best without it)
    nominal_objective_b: float = math.nan  # robust problems: B of the best parameters on the nominal robot


#: A tuned parameter within this fraction of its search range of a bound is "on the bound".
BOUND_MARGIN = 0.01


def bound_warnings(method: str, best_params: Mapping[str, float], search: Mapping[str, tuple[float, float]]) -> list[str]:
    """Warnings for tuned parameters on a search bound that could be widened (a bound at the
    edge of the parameter's valid range cannot be, and is not flagged): the optimum may lie
    beyond it."""
    specs = {p.name: p for p in method_spec(method).params}
    out = []
    for name, value in best_params.items():
        lo, hi = search[name]
        margin = BOUND_MARGIN * (hi - lo)
        spec = specs[name]
        if value - lo <= margin and lo > spec.low:
            side, bound = "lower", lo
        elif hi - value <= margin and hi < spec.high:
            side, bound = "upper", hi
        else:
            continue
        out.append(
            f"{name} = {value:.4g} is on the {side} search bound {bound:g}: the optimum may lie beyond it; "
            f"widen bounds.{name} (valid range {spec.low:g} to {spec.high:g})"
        )
    return out


def run(
    problem: TuningProblem,
    ga: BinaryGA,
    termination: Termination,
    *,
    callback: Callable[[TuneProgress], None] | None = None,
    map_fn: MapFn = map,
    chunks: int = 1,
    seed: int | None = None,
    refine: bool = True,
) -> TuneResult:
    """Drive ``ga`` on ``problem`` until ``termination``: ask, evaluate, tell, one generation at
    a time; ``callback(progress)`` after each. Then, with ``refine`` and a feasible best,
    Nelder-Mead from it (:func:`engine.tuning.refine.refine`), the same callback after each of
    its records (``phase`` ``refine``). ``map_fn``/``chunks`` spread the GA's generations; the
    refinement's evaluations, one parameter set each, run in this process. A run stopped inside
    a generation keeps the best of the generations done; a run with no feasible individual is a
    failed result, not an exception."""
    start = time.perf_counter()
    interrupted = False
    search: Refinement | None = None

    def report(record: GenerationRecord, planned: int) -> None:
        if callback is not None:
            callback(
                TuneProgress(
                    record.generation,
                    termination.generations,
                    planned * problem.n_tasks * problem.samples,
                    record.best,
                    record.mean,
                    record.feasible,
                    record.best_params,
                    record.phase,
                )
            )

    while True:
        try:
            objective_b = problem.evaluate(ga.ask(), map_fn=map_fn, chunks=chunks, stop=termination)
        except EvaluationStoppedError:
            interrupted = True
            break
        done = ga.tell(objective_b)
        report(done, ga.planned)
        if termination.finished(done.generation):
            break
    if refine and not interrupted and not termination.is_set() and math.isfinite(ga.best_objective_b):
        evaluated, values = ga.evaluated()
        starts = [
            ({k: float(v[i]) for k, v in evaluated.items()}, float(values[i]))
            for i in starting_points(problem.bounds, evaluated, values)
        ]
        search = refine_best(
            problem.bounds,
            starts,
            ga.generation + 1,
            # in this process, never through map_fn: Nelder-Mead asks for one parameter set at a
            # time (some 2,000 on the paper task), a plan of 0.5 ms, while a round trip to a Dask
            # cluster takes 10-20 ms (with it, the default job took 20-27 times as long)
            lambda params: problem.evaluate(params, stop=termination),
            on_record=lambda record, planned: report(record, ga.planned + planned),
            stop=termination,
        )
        interrupted = search.stopped
    return result_of(problem, ga, termination, time.perf_counter() - start, seed, interrupted, search)


def result_of(
    problem: TuningProblem,
    ga: BinaryGA,
    termination: Termination,
    elapsed_s: float,
    seed: int | None,
    interrupted: bool,
    search: Refinement | None = None,
) -> TuneResult:
    """The result of a run that ended (``interrupted``: stopped inside a generation), the
    refinement's rounds (``search``) after the GA's generations."""
    method = problem.method.name
    if not ga.history:
        return TuneResult(
            method=method,
            best_params={},
            best_objective_b=math.inf,
            best_metrics=[],
            history=[],
            evaluations=0,
            elapsed_s=elapsed_s,
            seed=seed,
            success=False,
            message="stopped while the initial population was evaluated",
            stopped=True,
            bounds=problem.bounds,
        )
    best_params, best_b = ga.best_params, ga.best_objective_b
    if search is not None and search.best_objective_b < best_b:
        best_params, best_b = search.best_params, search.best_objective_b
    feasible = math.isfinite(best_b)
    stopped = interrupted or termination.reason is not None
    history = list(ga.history) + (list(search.history) if search is not None else [])
    last = history[-1].generation
    if not feasible:
        message = "no feasible parameters found: every individual broke the joint speed limit or diverged"
    elif interrupted:
        message = f"stopped during {'round' if search is not None else 'generation'} {last + 1}"
    elif stopped:
        message = f"stopped after generation {last}"
    else:
        message = "ok"
    planned = ga.planned + (search.planned if search is not None else 0)
    return TuneResult(
        method=method,
        best_params=best_params,
        best_objective_b=best_b,
        best_metrics=problem.metrics(best_params),
        history=history,
        evaluations=planned * problem.n_tasks * problem.samples,
        elapsed_s=elapsed_s,
        seed=seed,
        success=feasible,
        message=message,
        stopped=stopped,
        bounds=problem.bounds,
        cache_hits=ga.cache_hits + (search.cache_hits if search is not None else 0),
        warnings=bound_warnings(method, best_params, problem.bounds) if feasible else [],
        ga_objective_b=ga.best_objective_b,
        nominal_objective_b=problem.nominal().objective_b(best_params) if feasible and problem.robust is not None else math.nan,
    )


def tune(
    model: RobotModel,
    tasks: CartesianTask | Sequence[CartesianTask],
    method: str = "adaptive",
    *,
    bounds: Mapping[str, Sequence[float]] | None = None,
    population: int = 40,
    generations: int = 50,
    crossover_probability: float = 0.8,
    mutation_probability: float = 0.02,
    bits_per_gene: int = 16,
    elitism: int = 1,
    seed: int | np.random.Generator | None = 0,
    options: PlanOptions | None = None,
    task_aggregation: str = "mean",
    callback: Callable[[TuneProgress], None] | None = None,
    map_fn: MapFn = map,
    chunks: int = 1,
    termination: Termination | None = None,
    refine: bool = True,
    uncertainty: Uncertainty | None = None,
    robust_statistic: str = "mean",
    **option_fields: Any,
) -> TuneResult:
    """Tune ``method``'s parameters with the paper's binary GA to minimise ``B``.

    Plans run with ``options`` (or their keywords: ``feedback_gain``, ``weights``,
    ``aggregation``, ``attitude_term``, see :meth:`PlanOptions.of`). With several tasks the
    objective is their mean (``task_aggregation="mean"``) or worst (``"max"``). ``termination``
    (default: after ``generations``) may be cancelled from another thread or carry a deadline.
    ``refine`` runs the pattern search after the GA (``False``: the paper's GA alone). With
    ``uncertainty`` the tuning is robust: ``B`` is ``robust_statistic`` (mean, p95, max) over the
    sampled robots in closed loop (:class:`engine.tuning.problem.Robust`).
    """
    settings = GASettings(population, generations, crossover_probability, mutation_probability, bits_per_gene, elitism)
    if chunks < 1:
        raise ParameterError("chunks", "must be >= 1")
    problem = TuningProblem.build(
        model,
        tasks,
        method,
        bounds=bounds,
        options=options or PlanOptions.of(**option_fields),
        task_aggregation=task_aggregation,
        uncertainty=uncertainty,
        robust_statistic=robust_statistic,
    )
    ga = BinaryGA(problem.bounds, settings, seed)
    return run(
        problem,
        ga,
        termination or Termination(generations),
        callback=callback,
        map_fn=map_fn,
        chunks=chunks,
        seed=seed if isinstance(seed, int) else None,
        refine=refine,
    )


@dataclass(frozen=True)
class Comparison:
    """The paper's comparison, tuned DLS versus tuned adaptive damping, same objective, with a
    third row: the ``bounded`` inverse (DLS held within the joint limits by a QP) tuned alike."""

    adaptive: TuneResult
    dls: TuneResult
    improvement_percent: float  # 100 (B_dls - B_adaptive) / B_dls; nan if either infeasible
    bounded: TuneResult | None = None  # None when compare() was asked for two rows only
    bounded_improvement_percent: float = math.nan  # 100 (B_dls - B_bounded) / B_dls

    def rows(self) -> list[tuple[str, TuneResult, float]]:
        """``(label, result, improvement over the tuned DLS in %)`` per row, DLS first."""
        out = [("dls", self.dls, 0.0), (self.adaptive.method, self.adaptive, self.improvement_percent)]
        if self.bounded is not None:
            out.append(("bounded", self.bounded, self.bounded_improvement_percent))
        return out


def improvement_percent(b_baseline: float, b_new: float) -> float:
    if not (math.isfinite(b_baseline) and math.isfinite(b_new)) or b_baseline <= 0.0:
        return math.nan
    return 100.0 * (b_baseline - b_new) / b_baseline


def compare(
    model: RobotModel,
    tasks: CartesianTask | Sequence[CartesianTask],
    *,
    method: str = "adaptive",
    bounds: Mapping[str, Sequence[float]] | None = None,
    dls_bounds: Mapping[str, Sequence[float]] | None = None,
    with_bounded: bool = True,
    bounded_bounds: Mapping[str, Sequence[float]] | None = None,
    **ga: Any,
) -> Comparison:
    """Tune ``method`` and the constant-damping DLS baseline with the same GA settings, limits
    and objective (a fair baseline: the best constant damping, not an arbitrary one), and with
    ``with_bounded`` the ``bounded`` inverse too (the third row)."""
    tuned = tune(model, tasks, method, bounds=bounds, **ga)
    baseline = tune(model, tasks, "dls", bounds=dls_bounds, **ga)
    b_dls = baseline.best_objective_b
    comparison = Comparison(tuned, baseline, improvement_percent(b_dls, tuned.best_objective_b))
    if not with_bounded:
        return comparison
    bounded = tune(model, tasks, "bounded", bounds=bounded_bounds, **ga)
    return replace(comparison, bounded=bounded, bounded_improvement_percent=improvement_percent(b_dls, bounded.best_objective_b))
