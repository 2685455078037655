"""Running one tuning job: the request is rebuilt into engine objects and handed to
:func:`engine.tuning.tune` (and the DLS baseline with the same GA settings, as
:func:`engine.tuning.compare` does). The per-generation callback writes progress; a watcher
thread renews the lease and, every second, looks for a cancellation, so a cancel (or a lost
lease, or a worker shutdown) stops the GA within a second or two, inside a generation.

Cost. A job is bounded up front by its work in *joint-steps*, the unit the planner's time is
proportional to (about a microsecond per joint-step on one core): population x (generations
+ 1) x the plan-steps of its tasks x the robot's joints, twice with the DLS baseline. Its memory
is bounded by design: the GA keeps a row of metrics per individual, never a trajectory.

Database faults (read-only, full, unreachable) stop the GA and give the job back to the queue
once the database answers again (retried with backoff), instead of failing it."""

from __future__ import annotations

import contextvars
import logging
import random
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from pydantic import ValidationError

from engine import RobotModel, TuneProgress, TuneResult, tune
from engine.errors import ParameterError
from engine.inverses import METHODS
from engine.tuning import MapFn, check_bounds, improvement_percent
from service import queue
from service.convert import build_task, clean, field_path, metrics_out, resolve_robot
from service.errors import ApiError, ApiValidationError
from service.infra.db import Database, is_database_fault, unavailable_reason
from service.models import TuningJob
from service.schemas.tuning import TuningJobRequest

log = logging.getLogger("spacearm.worker")
T = TypeVar("T")

MAX_PLAN_EVALUATIONS = 200_000
#: Joint-steps a job may need (about 2 h of one core, 1 h on two, at a microsecond each).
MAX_JOB_JOINT_STEPS = 7_000_000_000
#: How often the watcher looks for a cancellation (s).
CANCEL_POLL_S = 1.0


def planned_evaluations(body: TuningJobRequest) -> int:
    """The plan evaluations a job may need: every individual of every generation (and the initial
    population) on every task, twice with the DLS baseline."""
    return body.ga.population * (body.ga.generations + 1) * len(body.tasks) * (2 if body.compare_with_dls else 1)


def planned_joint_steps(body: TuningJobRequest, n_joints: int, steps_per_task: list[int]) -> int:
    """The work a job may need in joint-steps: population x (generations + 1) x the plan-steps of
    its tasks (each ``n_steps + 1`` samples) x joints, twice with the DLS baseline."""
    runs = body.ga.population * (body.ga.generations + 1) * (2 if body.compare_with_dls else 1)
    return runs * sum(steps_per_task) * n_joints


def validate_request(model: RobotModel, body: TuningJobRequest) -> None:
    """Everything the GA would reject, checked up front so a bad job is a 422, not a failure."""
    if body.method not in METHODS or not METHODS[body.method].params:
        tunable = [name for name, spec in METHODS.items() if spec.params]
        raise ApiValidationError(
            f"method: {body.method!r} cannot be tuned; choose one of {', '.join(tunable)}",
            [{"loc": ["body", "method"], "msg": f"must be one of {', '.join(tunable)}"}],
        )
    try:
        check_bounds(body.method, body.bounds.given() if body.bounds else None)
    except ParameterError as exc:
        loc = ["body", *field_path(exc.field)]
        raise ApiValidationError(str(exc), [{"loc": loc, "msg": exc.reason}]) from None
    twice = " * 2 (compare_with_dls)" if body.compare_with_dls else ""
    evaluations = planned_evaluations(body)
    if evaluations > MAX_PLAN_EVALUATIONS:
        msg = f"population * (generations + 1) * tasks{twice} = {evaluations} plan evaluations, at most {MAX_PLAN_EVALUATIONS}"
        raise ApiValidationError(f"ga: {msg}", [{"loc": ["body", "ga"], "msg": msg}])
    steps = [build_task(model, task, ("body", "tasks", i)).n_steps + 1 for i, task in enumerate(body.tasks)]
    work = planned_joint_steps(body, model.n_joints, steps)
    if work > MAX_JOB_JOINT_STEPS:
        msg = (
            f"population * (generations + 1){twice} * plan-steps of the tasks ({sum(steps)}) * joints ({model.n_joints}) "
            f"= {work:.3g} joint-steps, at most {MAX_JOB_JOINT_STEPS:.3g} per job (about a microsecond each: "
            f"{work * 1e-6 / 3600:.1g} h of one core): use fewer generations, a smaller population, fewer or "
            "shorter tasks, or a coarser dt_s"
        )
        raise ApiValidationError(f"ga: {msg}", [{"loc": ["body", "ga"], "msg": msg}])


def with_retries(fn: Callable[[], T], stop: threading.Event, deadline_s: float, what: str) -> T | None:
    """``fn()``, retried with jittered backoff while the database is faulty; None if ``stop`` is
    set or ``deadline_s`` passes first."""
    deadline = time.monotonic() + deadline_s
    delay = 0.25
    while True:
        try:
            return fn()
        except Exception as exc:
            if not is_database_fault(exc):
                raise
            if stop.is_set() or time.monotonic() + delay > deadline:
                log.warning("%s: the database is still unavailable, giving up", what)
                return None
            log.warning("%s: the database is unavailable (%s); retrying in %.1f s", what, unavailable_reason(exc), delay)
            stop.wait(delay * (0.5 + random.random()))
            delay = min(delay * 2.0, 10.0)


def _progress(
    p: TuneProgress,
    phase: str,
    role: str,
    offset: int,
    total: int,
    evaluations_before: int,
    history: list[dict[str, Any]],
    attempt: int,
) -> dict[str, Any]:
    """Progress of the running job; ``history`` (one row per finished generation and phase, for
    the per-phase history, the event stream and the convergence figure) is kept in it."""
    history.append(
        clean(
            {
                "phase": phase,
                "role": role,
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
            "attempt": attempt,  # the history below is this attempt's (event ids carry it)
        }
    )
    progress["history"] = history  # rows were cleaned as they were added
    return progress


def run_job(
    db: Database,
    claim: queue.Claim,
    lease_seconds: float,
    shutdown: threading.Event,
    *,
    map_fn: MapFn = map,
    chunks: int = 1,
) -> str:
    """Run a claimed job to its end. Returns the final status written, or ``"lost"`` (another
    worker owns it now) or ``"requeued"`` (given back: worker shutdown, database fault).
    ``map_fn``/``chunks`` spread each generation's evaluation (a Dask cluster's map, see
    :mod:`service.worker`)."""
    stop = threading.Event()  # cancel, lost lease, shutdown or database fault: the GA stops
    reasons: list[str] = []

    def halt(reason: str) -> None:
        if reason not in reasons:
            reasons.append(reason)
        stop.set()

    def give_back() -> str:
        ok = with_retries(lambda: queue.requeue(db, claim), shutdown, 3 * lease_seconds, f"job {claim.job_id}: giving it back")
        return "requeued" if ok else "lost"

    def load() -> tuple[TuningJobRequest, RobotModel] | None:
        with db.session() as s:
            job = s.get(TuningJob, claim.job_id)
            if job is None:
                return None
            request = dict(job.request)
            body = TuningJobRequest.model_validate(request)
            _, model = resolve_robot(s, body.robot_id, body.robot)
        return body, model

    def fail(message: str) -> str:
        ok = with_retries(lambda: queue.fail(db, claim, message), shutdown, 3 * lease_seconds, f"job {claim.job_id}: failing it")
        return "failed" if ok else "lost"

    try:
        loaded = with_retries(load, shutdown, 3 * lease_seconds, f"job {claim.job_id}: loading it")
    except ApiError as exc:
        return fail(f"invalid job: {exc.detail}")
    except ValidationError as exc:  # a request stored by an older version that no longer validates
        return fail(f"invalid job: {exc.error_count()} validation error(s): {exc.errors()[0]['msg']}")
    if loaded is None:
        return "lost" if not shutdown.is_set() else give_back()
    body, model = loaded
    try:
        tasks = [build_task(model, t, ("tasks", i)) for i, t in enumerate(body.tasks)]
    except ApiError as exc:
        return fail(f"invalid job: {exc.detail}")

    phases = [(body.method, body.bounds.given() if body.bounds else None)] + ([("dls", None)] if body.compare_with_dls else [])
    gens = body.ga.generations
    total = gens * len(phases)
    history: list[dict[str, Any]] = []

    def make_callback(phase: str, role: str, offset: int, evaluations_before: int) -> Callable[[TuneProgress], bool]:
        def callback(p: TuneProgress) -> bool:
            progress = _progress(p, phase, role, offset, total, evaluations_before, history, claim.attempts)
            log.info(
                "job %s: %s generation %d/%d, best B %.6g, %d feasible",
                claim.job_id,
                phase,
                p.generation,
                p.generations,
                p.best_objective_b,
                p.feasible,
            )
            try:
                state = queue.heartbeat(db, claim, lease_seconds, progress)
            except Exception as exc:
                if not is_database_fault(exc):
                    raise
                halt("database")
                return True
            if state != "ok":
                halt(state)
            return stop.is_set()

        return callback

    done = threading.Event()

    def watch() -> None:
        """Renew the lease and look for a cancellation every second, and pass a shutdown on."""
        failing_since: float | None = None
        while not done.wait(min(CANCEL_POLL_S, lease_seconds / 3.0)):
            if shutdown.is_set():
                halt("shutdown")
            try:
                state = queue.heartbeat(db, claim, lease_seconds)
                failing_since = None
            except Exception as exc:
                if not is_database_fault(exc):
                    raise
                failing_since = failing_since or time.monotonic()
                if time.monotonic() - failing_since > lease_seconds / 2.0:
                    halt("database")  # the lease is running out: stop and give the job back
                continue
            if state != "ok":
                halt(state)

    # in a copy of this context: the watcher's log lines carry the job id too
    watcher = threading.Thread(target=contextvars.copy_context().run, args=(watch,), name=f"lease-{claim.job_id}", daemon=True)
    watcher.start()
    results: list[TuneResult] = []
    evaluations = 0
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
                callback=make_callback(method, "tuned" if index == 0 else "dls_baseline", index * gens, evaluations),
                map_fn=map_fn,
                chunks=chunks,
                stop=stop,
            )
            evaluations += result.evaluations
            results.append(result)
            if stop.is_set():
                break
    except Exception as exc:
        if is_database_fault(exc):
            halt("database")
        else:  # engine errors are permanent: record them, do not retry
            log.exception("job %s failed", claim.job_id)
            done.set()
            return fail(f"{type(exc).__name__}: {exc}")
    finally:
        done.set()
        watcher.join()

    if reasons:
        reason = reasons[0]
        log.info("job %s stopped: %s", claim.job_id, reason)
        if reason == "cancel":
            ok = with_retries(lambda: queue.mark_cancelled(db, claim), shutdown, 3 * lease_seconds, "cancelling it")
            return "cancelled" if ok else "lost"
        if reason in ("shutdown", "database"):
            return give_back()
        return "lost"

    tuned = results[0]
    if not tuned.success:
        return fail(tuned.message)
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
                {
                    "lambda": baseline.best_params.get("lambda"),
                    "objective_b": baseline.best_objective_b,
                    "warnings": baseline.warnings,
                }
                if baseline
                else None
            ),
            "improvement_over_dls_percent": (
                improvement_percent(baseline.best_objective_b, tuned.best_objective_b) if baseline else None
            ),
            "warnings": tuned.warnings,
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
            "attempt": claim.attempts,
            "history": history,
        }
    )
    finished = with_retries(
        lambda: queue.finish(db, claim, result_body, final_progress), shutdown, 3 * lease_seconds, "storing its result"
    )
    return "succeeded" if finished else "lost"
