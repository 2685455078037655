"""Running one tuning job (the worker's side): the request is converted once into the engine's
problems (the tuned method, then the DLS baseline with the same GA settings), and each GA runs
through the engine's one driver, a generation at a time (:func:`engine.tuning.run`: ask,
evaluate, tell). After each generation its callback makes one write (:func:`service.queue.heartbeat`) appends the
generation's row, updates the progress summary and renews the lease. Between those writes a
watcher thread renews the lease and, every second, looks for a cancellation, so a cancel (or a
lost lease, or a worker shutdown) stops the GA within a second or two, inside a generation: all
of them end the run through the job's one :class:`engine.tuning.Termination`.

Cost. A job is bounded up front by its work in *joint-steps* (:mod:`service.usecases.tuning_jobs`).
Its memory is bounded by design: the GA keeps a row of metrics per individual, never a trajectory.

Database faults (read-only, full, unreachable) stop the GA and give the job back to the queue
once the database answers again (retried with backoff), instead of failing it."""

from __future__ import annotations

import contextvars
import hashlib
import logging
import random
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

from pydantic import ValidationError
from sqlalchemy import delete

from engine.errors import ParameterError
from engine.tuning import BinaryGA, MapFn, Termination, TuneProgress, TuneResult, TuningProblem, run
from service import queue
from service.errors import ApiError
from service.infra import jsonio
from service.infra.db import Database, is_database_fault, unavailable_reason
from service.models import JobGeneration, TuningJob
from service.schemas.tuning import TuningJobRequest, TuningJobResult
from service.usecases import meshes, robots

log = logging.getLogger("spacearm.worker")
T = TypeVar("T")

#: How often the watcher looks for a cancellation (s).
CANCEL_POLL_S = 1.0


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


def job_seed(job_id: str) -> int:
    """The GA's seed of a job submitted with ``ga.seed`` null: random across jobs, but the same
    for every run of one job (a job given back to the queue runs the same GA again, so the
    generations its event stream has sent stay true), in [0, 2**63)."""
    return int.from_bytes(hashlib.sha256(job_id.encode()).digest()[:8], "big") >> 1


def describe(exc: Exception) -> str:
    """What is wrong with a stored request the worker cannot convert."""
    if isinstance(exc, ApiError):
        return exc.detail
    if isinstance(exc, ValidationError):
        return f"{exc.error_count()} validation error(s): {exc.errors()[0]['msg']}"
    location = getattr(exc, "api_location", None)
    if isinstance(exc, ParameterError) and location:
        return f"{'.'.join(str(p) for p in location[1:])}: {exc.reason}"
    return str(exc)


class _Job:
    """One claimed job's run: its database writes and its termination."""

    def __init__(self, db: Database, claim: queue.Claim, lease_seconds: float, shutdown: threading.Event) -> None:
        self.db = db
        self.claim = claim
        self.lease_seconds = lease_seconds
        self.shutdown = shutdown
        self.termination = Termination(0)
        self.records = 0

    def retry(self, fn: Callable[[], T], what: str) -> T | None:
        return with_retries(fn, self.shutdown, 3 * self.lease_seconds, f"job {self.claim.job_id}: {what}")

    def give_back(self) -> str:
        return "requeued" if self.retry(lambda: queue.requeue(self.db, self.claim), "giving it back") else "lost"

    def fail(self, message: str) -> str:
        return "failed" if self.retry(lambda: queue.fail(self.db, self.claim, message), "failing it") else "lost"

    def load(self) -> tuple[TuningJobRequest, list[TuningProblem]] | None:
        """The job's request and engine problems; its rows of this attempt are cleared (a run given
        back before kept them)."""
        with self.db.session() as s:
            job = s.get(TuningJob, self.claim.job_id)
            if job is None:
                return None
            body = TuningJobRequest.model_validate(dict(job.request))
            _, model = robots.resolve(s, body.robot_id, body.robot, new=False)  # as queued, even by an older version
            s.execute(delete(JobGeneration).where(JobGeneration.job_id == job.id, JobGeneration.attempt == self.claim.attempts))
            with meshes.hulls(s):
                return body, body.problems(model)

    def write(self, progress: dict[str, Any], row: dict[str, Any]) -> None:
        """A finished generation: its row and the progress summary, one write."""
        try:
            state = queue.heartbeat(self.db, self.claim, self.lease_seconds, progress, row)
        except Exception as exc:
            if not is_database_fault(exc):
                raise
            self.termination.cancel("database")
            return
        if state != "ok":
            self.termination.cancel(state)

    def pass_shutdown_on(self) -> None:
        """The worker is stopping: end the run (the job goes back to the queue)."""
        if self.shutdown.is_set():
            self.termination.cancel("shutdown")

    def watch(self, done: threading.Event) -> None:
        """Renew the lease and look for a cancellation every second, and pass a shutdown on."""
        failing_since: float | None = None
        while not done.wait(min(CANCEL_POLL_S, self.lease_seconds / 3.0)):
            self.pass_shutdown_on()
            try:
                state = queue.heartbeat(self.db, self.claim, self.lease_seconds)
                failing_since = None
            except Exception as exc:
                if not is_database_fault(exc):
                    raise
                failing_since = failing_since or time.monotonic()
                if time.monotonic() - failing_since > self.lease_seconds / 2.0:
                    self.termination.cancel("database")  # the lease is running out: stop and give the job back
                continue
            if state != "ok":
                self.termination.cancel(state)

    def phase(
        self, body: TuningJobRequest, index: int, problem: TuningProblem, role: str, evaluations: int, map_fn: MapFn, chunks: int
    ) -> TuneResult:
        """One GA run (the engine's :func:`engine.tuning.run`), each generation written as it ends."""
        generations = body.ga.generations
        total = generations * len(body.phases())
        method = problem.method.name

        def written(done: TuneProgress) -> None:
            self.records += 1
            self.pass_shutdown_on()  # sooner than the watcher's next look: stop inside the next generation
            if done.phase == "refine":  # its records continue the GA's numbering
                step = f"refinement round {done.generation - generations}"
            else:
                step = f"generation {done.generation}/{generations}"
            log.info(
                "job %s: %s %s, best B %.6g, %d feasible",
                self.claim.job_id,
                method,
                step,
                done.best_objective_b,
                done.feasible,
            )
            progress = {
                "generation": index * generations + min(done.generation, generations),
                "generations": total,
                "evaluations": evaluations + done.evaluations,
                "best_objective_b": done.best_objective_b,
                "best_params": done.best_params,
                "phase": method,
                "attempt": self.claim.attempts,  # the rows of this attempt are the job's history
                "records": self.records,
            }
            row = {
                "seq": self.records,
                "phase": method,
                "role": role,
                "stage": done.phase,
                "generation": done.generation,
                "best": done.best_objective_b,
                "mean": done.mean_objective_b,
                "feasible": done.feasible,
            }
            self.write(jsonio.clean(progress), jsonio.clean(row))

        seed = job_seed(self.claim.job_id) if body.ga.seed is None else body.ga.seed
        ga = BinaryGA(problem.bounds, body.ga.to_engine(), seed)
        return run(problem, ga, self.termination, callback=written, map_fn=map_fn, chunks=chunks, seed=seed, refine=body.refine)


def cancelled_result(body: TuningJobRequest, results: list[TuneResult], evaluations: int) -> dict[str, Any] | None:
    """The result a cancelled job keeps: the best parameters its GA found before it stopped (and
    the DLS baseline's, if that phase had finished a generation); None if no generation of the
    tuned method finished."""
    if not results or not results[0].history:
        return None
    by_role = {role: result for result, (_, role, _) in zip(results, body.phases(), strict=False) if result.history}
    tuned = results[0]
    generations = body.ga.generations
    parts = [f"cancelled after generation {tuned.history[-1].generation} of {generations} of the {tuned.method} GA"]
    for role, what in (("dls_baseline", "the DLS baseline"), ("bounded_baseline", "the bounded inverse")):
        done = by_role.get(role)
        if done is not None:
            parts.append(f"and generation {done.history[-1].generation} of {generations} of {what}'s")
        elif any(r == role for _, r, _ in body.phases()):
            parts.append(f"before {what}'s GA finished a generation (no {role.replace('_', ' ')})")
    message = " ".join(parts) + ": the best parameters found by then"
    outcome = TuningJobResult.from_engine(
        tuned,
        by_role.get("dls_baseline"),
        evaluations,
        sum(r.elapsed_s for r in results),
        status="cancelled",
        message=message,
        bounded=by_role.get("bounded_baseline"),
    )
    stored: dict[str, Any] = jsonio.clean(outcome.model_dump(mode="json", by_alias=True))
    return stored


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
    job = _Job(db, claim, lease_seconds, shutdown)
    try:
        loaded = job.retry(job.load, "loading it")
    except (ApiError, ValidationError, ParameterError) as exc:  # a request this version cannot run
        return job.fail(f"invalid job: {describe(exc)}")
    if loaded is None:
        return "lost" if not shutdown.is_set() else job.give_back()
    body, problems = loaded
    job.termination = Termination(body.ga.generations)

    done = threading.Event()
    # in a copy of this context: the watcher's log lines carry the job id too
    watcher = threading.Thread(
        target=contextvars.copy_context().run, args=(job.watch, done), name=f"lease-{claim.job_id}", daemon=True
    )
    watcher.start()
    results: list[TuneResult] = []
    evaluations = 0
    try:
        for index, (problem, (_, role, _)) in enumerate(zip(problems, body.phases(), strict=True)):
            result = job.phase(body, index, problem, role, evaluations, map_fn, chunks)
            evaluations += result.evaluations
            results.append(result)
            if job.termination.is_set():
                break
    except Exception as exc:
        if is_database_fault(exc):
            job.termination.cancel("database")
        else:  # engine errors are permanent: record them, do not retry
            log.exception("job %s failed", claim.job_id)
            done.set()
            return job.fail(f"{type(exc).__name__}: {exc}")
    finally:
        done.set()
        watcher.join()

    reason = job.termination.reason
    if reason is not None:
        log.info("job %s stopped: %s", claim.job_id, reason)
        if reason == "cancel":
            best = cancelled_result(body, results, evaluations)
            ok = job.retry(lambda: queue.mark_cancelled(db, claim, best), "cancelling it")
            return "cancelled" if ok else "lost"
        if reason in ("shutdown", "database"):
            return job.give_back()
        return "lost"

    tuned = results[0]
    if not tuned.success:
        return job.fail(tuned.message)
    by_role = {role: result for result, (_, role, _) in zip(results, body.phases(), strict=True)}
    nominal = by_role.get("nominal_tuned")
    robust = None
    if nominal is not None and nominal.success:
        # the nominal tuning's parameters on the robust job's samples: what robust tuning gains
        robust = (nominal, problems[0].objective_b(nominal.best_params))
    outcome = TuningJobResult.from_engine(
        tuned,
        by_role.get("dls_baseline"),
        evaluations,
        sum(r.elapsed_s for r in results),
        bounded=by_role.get("bounded_baseline"),
        robust=robust,
        body=body,
    )
    final = jsonio.clean(
        {
            "generation": body.ga.generations * len(problems),
            "generations": body.ga.generations * len(problems),
            "evaluations": evaluations,
            "best_objective_b": tuned.best_objective_b,
            "best_params": tuned.best_params,
            "phase": "done",
            "attempt": claim.attempts,
            "records": job.records,
        }
    )
    stored = outcome.model_dump(mode="json", by_alias=True)
    finished = job.retry(lambda: queue.finish(db, claim, stored, final), "storing its result")
    return "succeeded" if finished else "lost"
