"""GA tuning of an inverse's parameters (paper sections 3.2 and 4), built on DEAP.

The paper's binary GA: each parameter is a gene of ``bits_per_gene`` bits decoded linearly onto
its bounds; roulette selection, one-point crossover, bit-flip mutation, and a new population
every generation that keeps the best ``elitism`` individuals (so the best objective never gets
worse, as in the paper's Figure 7).

Fitness. Roulette selection needs a positive fitness to maximise while the objective ``B``
(eqs. 17-19) is minimised and is +inf for an infeasible individual. We use
``fitness = 1 / B`` (``B`` floored at 1e-12) and give infeasible individuals the fitness
``1e-9``, so they are almost never selected but roulette still works when every individual is
infeasible. ``1 / (1 + B)`` would be nearly constant for ``B`` of a few millimetres, leaving
roulette no selection pressure.

Randomness. DEAP's operators (``tools.selRoulette``, ``tools.cxOnePoint``,
``tools.mutFlipBit``) draw from Python's global ``random`` module. Each generation draws a
seed from the run's ``numpy.random.Generator`` and runs the operators under a lock with the
global state seeded from it, then restores the global state: same seed, same result, and
runs in other threads do not disturb each other.

Evaluation. A whole population is evaluated with :func:`engine.planner.plan_batch` (genomes seen before are not planned again),
split into
``chunks`` handed to ``map_fn`` (the builtin ``map`` by default; a process pool's or a Dask
client's map spread it over processes or machines).
"""

from __future__ import annotations

import functools
import itertools
import math
import random
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from deap import base, creator, tools

from engine.errors import ParameterError
from engine.inverses import method_spec
from engine.metrics import Metrics, Objective
from engine.model import RobotModel
from engine.planner import EvaluationStoppedError, plan_batch
from engine.spatial import FloatArray
from engine.trajectory import CartesianTask

INFEASIBLE_FITNESS = 1e-9
MAX_POPULATION = 1000
MAX_GENERATIONS = 1000
MAX_BITS_PER_GENE = 52  # a float64 mantissa: more bits cannot be decoded exactly
TASK_AGGREGATIONS = ("mean", "max")

MapFn = Callable[[Callable[[Any], Any], Iterable[Any]], Iterable[Any]]

_RANDOM_LOCK = threading.Lock()

if not hasattr(creator, "SpacearmFitness"):
    creator.create("SpacearmFitness", base.Fitness, weights=(1.0,))
if not hasattr(creator, "SpacearmIndividual"):
    creator.create("SpacearmIndividual", list, fitness=creator.SpacearmFitness)


@contextmanager
def _seeded_global_random(seed: int) -> Any:
    """Run DEAP's operators on a global ``random`` state seeded from ``seed``; restore after."""
    with _RANDOM_LOCK:
        saved = random.getstate()
        random.seed(seed)
        try:
            yield
        finally:
            random.setstate(saved)


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


@dataclass(frozen=True)
class GenerationRecord:
    generation: int
    best: float  # best B so far
    mean: float  # mean B of the feasible individuals of this generation
    feasible: int
    best_params: dict[str, float]


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


def check_bounds(method: str, bounds: Mapping[str, Sequence[float]] | None) -> dict[str, tuple[float, float]]:
    """Validate search bounds: every parameter of ``method`` tuned, ``lo < hi`` within its valid
    range. Missing parameters take their default bounds."""
    spec = method_spec(method)
    if not spec.params:
        raise ParameterError("method", f"method {method!r} has no parameters to tune")
    known = {p.name: p for p in spec.params}
    bounds = dict(bounds or {})
    unknown = set(bounds) - set(known)
    if unknown:
        raise ParameterError(
            f"bounds.{min(unknown)}", f"unknown parameter(s) {', '.join(sorted(unknown))} for {method}; valid: {', '.join(known)}"
        )
    out: dict[str, tuple[float, float]] = {}
    for name, p in known.items():
        pair = bounds.get(name, p.tune_bounds)
        if len(pair) != 2:
            raise ParameterError(f"bounds.{name}", "expected [lo, hi]")
        lo, hi = (float(x) for x in pair)
        p.check(np.array([lo, hi]), f"bounds.{name}")
        if not lo < hi:
            raise ParameterError(f"bounds.{name}", f"lo must be < hi, got [{lo}, {hi}]")
        out[name] = (lo, hi)
    return out


def decode(bits: np.ndarray, bounds: Mapping[str, tuple[float, float]], bits_per_gene: int) -> dict[str, FloatArray]:
    """Decode genomes ``bits (B, G * bits_per_gene)`` (0/1) to parameter arrays ``(B,)``:
    gene g's bits, most significant first, give an integer mapped linearly onto its bounds."""
    weights = 2.0 ** np.arange(bits_per_gene - 1, -1, -1)
    top = 2.0**bits_per_gene - 1.0
    out = {}
    for g, (name, (lo, hi)) in enumerate(bounds.items()):
        ints = bits[:, g * bits_per_gene : (g + 1) * bits_per_gene] @ weights
        out[name] = lo + (hi - lo) * ints / top
    return out


@dataclass(frozen=True)
class _Chunk:
    model: RobotModel
    tasks: tuple[CartesianTask, ...]
    method: str
    params: dict[str, FloatArray]
    objective: Objective
    feedback_gain: float


def evaluate_chunk(chunk: _Chunk, stop: threading.Event | None = None) -> FloatArray:
    """Objective ``B`` of each parameter set on each task, ``(B, n_tasks)``. Top-level so a
    process pool or a Dask worker can run it; ``stop`` (in process only) interrupts it with
    :class:`engine.planner.EvaluationStoppedError`."""
    columns = [
        plan_batch(
            chunk.model,
            task,
            chunk.method,
            chunk.params,
            feedback_gain=chunk.feedback_gain,
            weights=chunk.objective.weights,
            aggregation=chunk.objective.aggregation,
            attitude_term=chunk.objective.attitude_term,
            stop=stop,
        ).objective_b
        for task in chunk.tasks
    ]
    return np.stack(columns, axis=1)


def _evaluate(
    map_fn: MapFn,
    chunks: int,
    base_chunk: _Chunk,
    params: dict[str, FloatArray],
    task_aggregation: str,
    stop: threading.Event | None = None,
) -> FloatArray:
    size = next(iter(params.values())).shape[0]
    edges = np.linspace(0, size, min(chunks, size) + 1).astype(int)
    parts = [
        _Chunk(**{**base_chunk.__dict__, "params": {k: v[a:b] for k, v in params.items()}}) for a, b in itertools.pairwise(edges)
    ]
    # a stop request reaches plans evaluated in this process; remote ones finish their generation
    fn = functools.partial(evaluate_chunk, stop=stop) if stop is not None and map_fn is map else evaluate_chunk
    per_task = np.concatenate([np.asarray(r) for r in map_fn(fn, parts)], axis=0)
    if task_aggregation == "max":
        return np.max(per_task, axis=1)
    return np.mean(per_task, axis=1)  # inf on any task stays inf


def dask_map(client: Any) -> MapFn:
    """A ``map_fn`` that spreads the chunks over a Dask cluster: ``client.map`` then
    ``client.gather`` (``client`` is a ``distributed.Client``; Dask is not imported here)."""

    def mapper(fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterable[Any]:
        futures = client.map(fn, list(items), pure=False)
        results: list[Any] = client.gather(futures)
        return results

    return mapper


def _fitness(b: float) -> float:
    return 1.0 / max(b, 1e-12) if math.isfinite(b) else INFEASIBLE_FITNESS


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
    weights: tuple[float, float] = (0.5, 0.5),
    aggregation: str = "max",
    attitude_term: str = "eq18",
    task_aggregation: str = "mean",
    feedback_gain: float = 0.0,
    callback: Callable[[TuneProgress], bool | None] | None = None,
    map_fn: MapFn = map,
    chunks: int = 1,
    stop: threading.Event | None = None,
) -> TuneResult:
    """Tune ``method``'s parameters with the paper's binary GA to minimise ``B``.

    ``mutation_probability`` is the per-bit flip probability (DEAP's ``indpb``) applied to
    every offspring; ``crossover_probability`` the chance that a pair is crossed. With several
    tasks the objective is their mean (``task_aggregation="mean"``) or worst (``"max"``).
    ``callback(progress)`` returning ``True`` stops the run after that generation; setting the
    ``stop`` event stops it within a generation (plans already running finish; with the builtin
    ``map``, about a twentieth of a second later), keeping the best of the generations done. A
    run with no feasible individual returns ``success=False`` with a message, not an exception.
    """
    task_list = (tasks,) if isinstance(tasks, CartesianTask) else tuple(tasks)
    if not task_list:
        raise ParameterError("tasks", "at least one task is needed")
    for i, task in enumerate(task_list):
        if task.q0.shape != (model.n_joints,):
            raise ParameterError(f"tasks[{i}].q0", f"expected {model.n_joints} joint angles, got {task.q0.shape[0]}")
    search = check_bounds(method, bounds)
    if not 2 <= population <= MAX_POPULATION:
        raise ParameterError("population", f"must be in [2, {MAX_POPULATION}]")
    if not 1 <= generations <= MAX_GENERATIONS:
        raise ParameterError("generations", f"must be in [1, {MAX_GENERATIONS}]")
    if not 0.0 <= crossover_probability <= 1.0:
        raise ParameterError("crossover_probability", "must be in [0, 1]")
    if not 0.0 <= mutation_probability <= 1.0:
        raise ParameterError("mutation_probability", "must be in [0, 1]")
    if not 2 <= bits_per_gene <= MAX_BITS_PER_GENE:
        raise ParameterError("bits_per_gene", f"must be in [2, {MAX_BITS_PER_GENE}]")
    if not 0 <= elitism < population:
        raise ParameterError("elitism", "must be in [0, population - 1]")
    if task_aggregation not in TASK_AGGREGATIONS:
        raise ParameterError("task_aggregation", f"must be one of {', '.join(TASK_AGGREGATIONS)}")
    if chunks < 1:
        raise ParameterError("chunks", "must be >= 1")
    objective = Objective(weights, aggregation, attitude_term)

    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    seed_value = seed if isinstance(seed, int) else None
    n_bits = bits_per_gene * len(search)
    toolbox = base.Toolbox()
    toolbox.register("select", tools.selRoulette)
    toolbox.register("mate", tools.cxOnePoint)
    toolbox.register("mutate", tools.mutFlipBit, indpb=mutation_probability)
    base_chunk = _Chunk(model, task_list, method, {}, objective, feedback_gain)

    # B of every genome seen so far: a converging population repeats genomes, and the
    # objective is a deterministic function of the genome, so each is planned once.
    known: dict[tuple[int, ...], float] = {}

    def evaluate(individuals: list[Any]) -> int:
        """Set ``objective_b`` and fitness; returns the number of genomes actually planned."""
        fresh = list(dict.fromkeys(tuple(ind) for ind in individuals if tuple(ind) not in known))
        if fresh:
            bits = np.array(fresh, dtype=float)
            objective = _evaluate(map_fn, chunks, base_chunk, decode(bits, search, bits_per_gene), task_aggregation, stop)
            known.update(zip(fresh, (float(b) for b in objective), strict=True))
        for ind in individuals:
            ind.objective_b = known[tuple(ind)]
            ind.fitness.values = (_fitness(ind.objective_b),)
        return len(fresh)

    def params_of(ind: Any) -> dict[str, float]:
        decoded = decode(np.array([ind], dtype=float), search, bits_per_gene)
        return {k: float(v[0]) for k, v in decoded.items()}

    start = time.perf_counter()
    pop = [creator.SpacearmIndividual(row) for row in rng.integers(0, 2, size=(population, n_bits)).tolist()]
    try:
        planned = evaluate(pop)
    except EvaluationStoppedError:
        return TuneResult(
            method=method,
            best_params={},
            best_objective_b=math.inf,
            best_metrics=[],
            history=[],
            evaluations=0,
            elapsed_s=time.perf_counter() - start,
            seed=seed_value,
            success=False,
            message="stopped while the initial population was evaluated",
            stopped=True,
            bounds=search,
        )
    evaluations = planned * len(task_list)
    cache_hits = population - planned
    best = min(pop, key=lambda ind: ind.objective_b)
    history: list[GenerationRecord] = []

    def record(generation: int) -> bool:
        feasible = [ind.objective_b for ind in pop if math.isfinite(ind.objective_b)]
        mean_b = float(np.mean(feasible)) if feasible else math.inf
        best_params = params_of(best)
        history.append(GenerationRecord(generation, best.objective_b, mean_b, len(feasible), best_params))
        if callback is None:
            return False
        progress = TuneProgress(generation, generations, evaluations, best.objective_b, mean_b, len(feasible), best_params)
        return bool(callback(progress))

    stopped = record(0)
    interrupted = False
    for generation in range(1, generations + 1):
        if stopped:
            break
        elite = [toolbox.clone(ind) for ind in tools.selBest(pop, elitism)] if elitism else []
        with _seeded_global_random(int(rng.integers(2**63 - 1))):
            offspring = [toolbox.clone(ind) for ind in toolbox.select(pop, population - len(elite))]
            for a, b in zip(offspring[::2], offspring[1::2], strict=False):
                if random.random() < crossover_probability:
                    toolbox.mate(a, b)
            for ind in offspring:
                toolbox.mutate(ind)
        try:
            planned = evaluate(offspring)
        except EvaluationStoppedError:
            stopped = interrupted = True
            break
        evaluations += planned * len(task_list)
        cache_hits += len(offspring) - planned
        pop = elite + offspring
        generation_best = min(pop, key=lambda ind: ind.objective_b)
        if generation_best.objective_b < best.objective_b:
            best = toolbox.clone(generation_best)
            best.objective_b = generation_best.objective_b
        stopped = record(generation)

    best_params = params_of(best)
    best_metrics = [
        plan_batch(
            model,
            task,
            method,
            {k: [v] for k, v in best_params.items()},
            feedback_gain=feedback_gain,
            weights=objective.weights,
            aggregation=objective.aggregation,
            attitude_term=objective.attitude_term,
        ).metrics.item(0)
        for task in task_list
    ]
    elapsed = time.perf_counter() - start
    feasible = math.isfinite(best.objective_b)
    if not feasible:
        message = "no feasible parameters found: every individual broke the joint speed limit or diverged"
    elif interrupted:
        message = f"stopped during generation {history[-1].generation + 1}"
    elif stopped:
        message = f"stopped after generation {history[-1].generation}"
    else:
        message = "ok"
    return TuneResult(
        method=method,
        best_params=best_params,
        best_objective_b=best.objective_b,
        best_metrics=best_metrics,
        history=history,
        evaluations=evaluations,
        elapsed_s=elapsed,
        seed=seed_value,
        success=feasible,
        message=message,
        stopped=stopped,
        bounds=search,
        cache_hits=cache_hits,
        warnings=bound_warnings(method, best_params, search) if feasible else [],
    )


@dataclass(frozen=True)
class Comparison:
    """The paper's comparison: tuned DLS versus tuned adaptive damping, same objective."""

    adaptive: TuneResult
    dls: TuneResult
    improvement_percent: float  # 100 (B_dls - B_adaptive) / B_dls; nan if either infeasible


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
    **ga: Any,
) -> Comparison:
    """Tune ``method`` and the constant-damping DLS baseline with the same GA settings, speed
    limit and objective (a fair baseline: the best constant damping, not an arbitrary one)."""
    tuned = tune(model, tasks, method, bounds=bounds, **ga)
    baseline = tune(model, tasks, "dls", bounds=dls_bounds, **ga)
    return Comparison(tuned, baseline, improvement_percent(baseline.best_objective_b, tuned.best_objective_b))
