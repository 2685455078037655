"""The tuning problem: minimise the objective ``B`` (eqs. 17-19) over the parameters of one
inverse method on one or more tasks, evaluated a population at a time.

A population is split into ``chunks`` handed to ``map_fn`` (the builtin ``map`` by default; a
process pool's or a Dask client's map spreads them over processes or machines): each chunk is a
picklable :class:`Chunk` run by the top-level :func:`evaluate_chunk`. Within a process the
plans of a chunk are spread over the engine's threads (:func:`engine.planner.evaluate`)."""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from engine.errors import ParameterError
from engine.inverses import Method, method_spec
from engine.metrics import Metrics
from engine.model import RobotModel
from engine.planner import PlanOptions, PlanSetup, Stop, evaluate
from engine.robustness import sampled_setups, statistic
from engine.spatial import FloatArray
from engine.trajectory import CartesianTask
from engine.uncertainty import Uncertainty, draw

TASK_AGGREGATIONS = ("mean", "max")
#: What a robust tuning minimises over the samples' B.
ROBUST_STATISTICS = ("mean", "p95", "max")

MapFn = Callable[[Callable[[Any], Any], Iterable[Any]], Iterable[Any]]


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


@dataclass(frozen=True)
class Robust:
    """Robust tuning: ``B`` of a parameter set is ``statistic`` (mean, p95 or max) of its ``B``
    on each sampled robot in closed loop (infinite if any sample breaks a limit: eq. 19's ``P_l``
    over the samples); ``setups[k][s]`` runs task ``k`` on sample ``s``."""

    uncertainty: Uncertainty
    statistic: str
    setups: tuple[tuple[PlanSetup, ...], ...]


@dataclass(frozen=True)
class TuningProblem:
    """Minimise ``B`` of ``method`` over ``bounds`` on the checked ``setups`` (one per task,
    sharing their options), the tasks' values combined by their mean or worst
    (``task_aggregation``). Build it with :meth:`build`."""

    setups: tuple[PlanSetup, ...]
    method: Method
    bounds: dict[str, tuple[float, float]]
    task_aggregation: str = "mean"
    robust: Robust | None = None

    @classmethod
    def build(
        cls,
        model: RobotModel,
        tasks: CartesianTask | Sequence[CartesianTask],
        method: str = "adaptive",
        *,
        bounds: Mapping[str, Sequence[float]] | None = None,
        options: PlanOptions | None = None,
        task_aggregation: str = "mean",
        uncertainty: Uncertainty | None = None,
        robust_statistic: str = "mean",
    ) -> TuningProblem:
        """The problem, checked once: errors name ``tasks[i].<field>``, ``bounds.<name>``,
        ``method``, ``task_aggregation``, ``robust_statistic`` or an option. With
        ``uncertainty`` it is the robust problem (:class:`Robust`)."""
        task_list = (tasks,) if isinstance(tasks, CartesianTask) else tuple(tasks)
        if not task_list:
            raise ParameterError("tasks", "at least one task is needed")
        if task_aggregation not in TASK_AGGREGATIONS:
            raise ParameterError("task_aggregation", f"must be one of {', '.join(TASK_AGGREGATIONS)}")
        search = check_bounds(method, bounds)
        setups = PlanSetup.of_tasks(model, task_list, options or PlanOptions())
        robust = None
        if uncertainty is not None:
            if robust_statistic not in ROBUST_STATISTICS:
                raise ParameterError("robust_statistic", f"must be one of {', '.join(ROBUST_STATISTICS)}")
            samples = draw(uncertainty, model)
            robust = Robust(uncertainty, robust_statistic, tuple(tuple(sampled_setups(s, samples)) for s in setups))
        return cls(tuple(setups), method_spec(method), search, task_aggregation, robust)

    def nominal(self) -> TuningProblem:
        """The same problem on the nominal robot only."""
        return TuningProblem(self.setups, self.method, self.bounds, self.task_aggregation)

    @property
    def samples(self) -> int:
        """Robots each parameter set is planned on (1: the nominal one)."""
        return 1 if self.robust is None else self.robust.uncertainty.samples

    @property
    def n_tasks(self) -> int:
        return len(self.setups)

    def plan_steps(self) -> int:
        """The plan-steps of one evaluation of every task (``n_steps + 1`` samples each) on
        every sampled robot."""
        return sum(s.task.n_steps + 1 for s in self.setups) * self.samples

    def evaluate_tasks(self, params: Mapping[str, FloatArray], stop: Stop | None = None) -> FloatArray:
        """``B (B, n_tasks)`` of the parameter sets ``params`` (``{name: (B,)}``) on each task,
        in this process (``stop`` skips the plans not yet started: EvaluationStoppedError)."""
        inverse = self.method(**params)
        size = next(iter(params.values())).shape[0]
        if self.robust is None:
            columns = [s.metrics(evaluate(s, inverse, size, stop=stop)).objective_b for s in self.setups]
        else:
            columns = [
                statistic(
                    np.stack([s.metrics(evaluate(s, inverse, size, stop=stop)).objective_b for s in sampled], axis=1),
                    self.robust.statistic,
                )
                for sampled in self.robust.setups
            ]
        return np.stack(columns, axis=1)

    def evaluate(
        self, params: Mapping[str, FloatArray], *, map_fn: MapFn = map, chunks: int = 1, stop: Stop | None = None
    ) -> FloatArray:
        """``B (B,)`` of the parameter sets ``params``: the tasks' mean or worst (inf on any
        task stays inf), the sets split into ``chunks`` for ``map_fn``. ``stop`` reaches the plans
        evaluated in this process; remote ones finish their chunk."""
        size = next(iter(params.values())).shape[0]
        if size == 0:
            return np.zeros(0)
        edges = np.linspace(0, size, min(max(chunks, 1), size) + 1).astype(int)
        parts = [Chunk(self, {k: np.asarray(v)[a:b] for k, v in params.items()}) for a, b in itertools.pairwise(edges)]
        fn = functools.partial(evaluate_chunk, stop=stop) if stop is not None and map_fn is map else evaluate_chunk
        per_task = np.concatenate([np.asarray(r) for r in map_fn(fn, parts)], axis=0)
        if self.task_aggregation == "max":
            return np.max(per_task, axis=1)
        return np.mean(per_task, axis=1)

    def objective_b(self, params: Mapping[str, float]) -> float:
        """``B`` of one parameter set (robust: over the samples)."""
        return float(self.evaluate({k: np.array([v]) for k, v in params.items()})[0])

    def metrics(self, params: Mapping[str, float]) -> list[Metrics[float]]:
        """The metrics of one parameter set on each task (the nominal robot)."""
        inverse = self.method(**{k: np.array([v]) for k, v in params.items()})
        return [s.metrics(evaluate(s, inverse, 1)).item(0) for s in self.setups]


@dataclass(frozen=True)
class Chunk:
    """A piece of a population's evaluation that can be sent to another process."""

    problem: TuningProblem
    params: dict[str, FloatArray]


def evaluate_chunk(chunk: Chunk, stop: Stop | None = None) -> FloatArray:
    """``B (B, n_tasks)`` of a chunk (top-level, so a process pool or a Dask worker can run it)."""
    return chunk.problem.evaluate_tasks(chunk.params, stop)


def dask_map(client: Any) -> MapFn:
    """A ``map_fn`` that spreads the chunks over a Dask cluster: ``client.map`` then
    ``client.gather`` (``client`` is a ``distributed.Client``; Dask is not imported here)."""

    def mapper(fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterable[Any]:
        futures = client.map(fn, list(items), pure=False)
        results: list[Any] = client.gather(futures)
        return results

    return mapper
