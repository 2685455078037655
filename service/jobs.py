"""Running one tuning job: the request is rebuilt into engine objects and handed to
:func:`engine.tuning.tune` (and the DLS baseline with the same GA settings, as
:func:`engine.tuning.compare` does). The per-generation callback writes progress, renews the
lease and stops the GA on cancellation, on a lost lease or on worker shutdown."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from engine import RobotModel, TuneProgress, TuneResult, tune
from engine.errors import ParameterError
from engine.inverses import METHODS
from engine.tuning import MapFn, check_bounds, improvement_percent
from service import queue
from service.convert import build_task, clean, field_path, metrics_out, resolve_robot
from service.db import Database
from service.errors import ApiError, ApiValidationError
from service.models import TuningJob
from service.schemas import TuningJobRequest

log = logging.getLogger("spacearm.worker")


MAX_PLAN_EVALUATIONS = 200_000


def planned_evaluations(body: TuningJobRequest) -> int:
    """The plan evaluations a job may need: every individual of every generation (and the initial
    population) on every task, twice with the DLS baseline."""
    return body.ga.population * (body.ga.generations + 1) * len(body.tasks) * (2 if body.compare_with_dls else 1)


def validate_request(model: RobotModel, body: TuningJobRequest) -> None:
    """Everything the GA would reject, checked up front so a bad job is a 422, not a failure."""
    if body.method not in METHODS or not METHODS[body.method].params:
        tunable = [name for name, spec in METHODS.items() if spec.params]
        raise ApiValidationError(
            f"method: {body.method!r} cannot be tuned; choose one of {', '.join(tunable)}",
            [{"loc": ["body", "method"], "msg": f"must be one of {', '.join(tunable)}"}],
        )
    try:
        check_bounds(body.method, body.bounds)
    except ParameterError as exc:
        loc = ["body", *field_path(exc.field)]
        raise ApiValidationError(str(exc), [{"loc": loc, "msg": exc.reason}]) from None
    evaluations = planned_evaluations(body)
    if evaluations > MAX_PLAN_EVALUATIONS:
        msg = (
            f"population * (generations + 1) * tasks{' * 2 (compare_with_dls)' if body.compare_with_dls else ''} "
            f"= {evaluations} plan evaluations, at most {MAX_PLAN_EVALUATIONS} per job"
        )
        raise ApiValidationError(f"ga: {msg}", [{"loc": ["body", "ga"], "msg": msg}])
    for i, task in enumerate(body.tasks):
        build_task(model, task, ("body", "tasks", i))


def _progress(
    p: TuneProgress, phase: str, offset: int, total: int, evaluations_before: int, history: list[dict[str, Any]]
) -> dict[str, Any]:
    """Progress of the running job; ``history`` (one row per finished generation and phase, for
    the convergence figure) is kept in it while the job runs."""
    history.append(
        clean(
            {
                "phase": phase,
                "generation": p.generation,
                "best": p.best_objective_b,
                "mean": p.mean_objective_b,
                "feasible": p.feasible,
            }
        )
    )
    progress: dict[str, Any] = clean(
        {
            "generation": offset + p.generation,
            "generations": total,
            "evaluations": evaluations_before + p.evaluations,
            "best_objective_b": p.best_objective_b,
            "best_params": p.best_params,
            "phase": phase,
        }
    )
    progress["history"] = history  # rows were cleaned as they were added
    return progress


class JobStoppedError(Exception):
    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def run_job(
    db: Database,
    claim: queue.Claim,
    lease_seconds: float,
    shutdown: threading.Event,
    *,
    map_fn: MapFn = map,
    chunks: int = 1,
) -> str:
    """Run a claimed job to its end. Returns the final status written (or ``"lost"`` /
    ``"requeued"``). ``map_fn``/``chunks`` spread each generation's evaluation (a Dask
    cluster's map, see :mod:`service.worker`)."""
    with db.session() as s:
        job = s.get(TuningJob, claim.job_id)
        if job is None:
            return "lost"
        request = dict(job.request)
    try:
        body = TuningJobRequest.model_validate(request)
        with db.session() as s:
            _, model = resolve_robot(s, body.robot_id, body.robot)
        tasks = [build_task(model, t, ("tasks", i)) for i, t in enumerate(body.tasks)]
    except ApiError as exc:
        queue.fail(db, claim, f"invalid job: {exc.detail}")
        return "failed"

    phases = [(body.method, body.bounds)] + ([("dls", None)] if body.compare_with_dls else [])
    gens = body.ga.generations
    total = gens * len(phases)
    stop_reason: list[str] = []
    history: list[dict[str, Any]] = []

    def make_callback(phase: str, offset: int, evaluations_before: int) -> Callable[[TuneProgress], bool]:
        def callback(p: TuneProgress) -> bool:
            state = queue.heartbeat(db, claim, lease_seconds, _progress(p, phase, offset, total, evaluations_before, history))
            if state != "ok":
                stop_reason.append(state)
                return True
            if shutdown.is_set():
                stop_reason.append("shutdown")
                return True
            return False

        return callback

    results: list[TuneResult] = []
    evaluations = 0
    done = threading.Event()

    def keep_alive() -> None:  # renews the lease even if one generation is slow
        while not done.wait(max(lease_seconds / 3.0, 0.05)):
            if queue.heartbeat(db, claim, lease_seconds) == "lost":
                return

    pulse = threading.Thread(target=keep_alive, name=f"lease-{claim.job_id}", daemon=True)
    pulse.start()
    try:
        for index, (method, bounds) in enumerate(phases):
            result = tune(
                model,
                tasks,
                method,
                bounds=bounds,
                population=body.ga.population,
                generations=gens,
                crossover_probability=body.ga.crossover_probability,
                mutation_probability=body.ga.mutation_probability,
                bits_per_gene=body.ga.bits_per_gene,
                elitism=body.ga.elitism,
                seed=body.ga.seed,
                weights=(body.objective.weights[0], body.objective.weights[1]),
                aggregation=body.objective.aggregation,
                attitude_term=body.objective.attitude_term,
                task_aggregation=body.objective.task_aggregation,
                feedback_gain=body.feedback_gain,
                callback=make_callback(method if index == 0 else "dls", index * gens, evaluations),
                map_fn=map_fn,
                chunks=chunks,
            )
            evaluations += result.evaluations
            results.append(result)
            if stop_reason:
                raise JobStoppedError(stop_reason[0])
    except JobStoppedError as stopped:
        if stopped.reason == "cancel":
            queue.mark_cancelled(db, claim)
            return "cancelled"
        if stopped.reason == "shutdown":
            queue.requeue(db, claim)
            return "requeued"
        return "lost"
    except Exception as exc:  # engine errors are permanent: record them, do not retry
        log.exception("job %s failed", claim.job_id)
        queue.fail(db, claim, f"{type(exc).__name__}: {exc}")
        return "failed"
    finally:
        done.set()
        pulse.join()

    tuned = results[0]
    if not tuned.success:
        queue.fail(db, claim, tuned.message)
        return "failed"
    baseline = results[1] if len(results) > 1 else None
    result_body = clean(
        {
            "method": tuned.method,
            "best_params": tuned.best_params,
            "best_objective_b": tuned.best_objective_b,
            "best_metrics": [metrics_out(m) for m in tuned.best_metrics],
            "history": [
                {"generation": h.generation, "best": h.best, "mean": h.mean, "feasible": h.feasible} for h in tuned.history
            ],
            "evaluations": evaluations,
            "elapsed_s": sum(r.elapsed_s for r in results),
            "seed": tuned.seed,
            "bounds": {k: list(v) for k, v in tuned.bounds.items()},
            "dls_baseline": (
                {"lambda": baseline.best_params.get("lambda"), "objective_b": baseline.best_objective_b} if baseline else None
            ),
            "improvement_over_dls_percent": (
                improvement_percent(baseline.best_objective_b, tuned.best_objective_b) if baseline else None
            ),
        }
    )
    final_progress = clean(
        {
            "generation": total,
            "generations": total,
            "evaluations": evaluations,
            "best_objective_b": tuned.best_objective_b,
            "best_params": tuned.best_params,
            "phase": "done",
            "history": history,
        }
    )
    return "succeeded" if queue.finish(db, claim, result_body, final_progress) else "lost"
