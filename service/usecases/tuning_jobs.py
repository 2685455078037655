"""Tuning jobs as the API sees them: submit (checked up front, bounded by its work, idempotent),
read (status, progress with each GA phase's history from the job's generation rows), result,
cancel, delete. Workers run them (:mod:`service.usecases.tuning_run`)."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

from sqlalchemy import delete as sql_delete
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from engine import RobotModel
from engine.tuning import TuningProblem
from engine.tuning.refine import max_evaluations
from service import queue
from service.errors import ApiValidationError, ConflictError, TooManyRequestsError
from service.infra import jsonio
from service.infra.db import Database
from service.infra.quota import check_quota
from service.infra.settings import Settings
from service.models import JobGeneration, TuningJob
from service.schemas.tuning import (
    HistoryRecord,
    JobLinks,
    JobPhase,
    JobProgress,
    PhaseRole,
    Stage,
    TuningJobList,
    TuningJobOut,
    TuningJobRequest,
    TuningJobResult,
)
from service.usecases import meshes, robots, rows

RETRY_AFTER_S = 10  # Retry-After of a 429 (the queue is full)
MAX_PLAN_EVALUATIONS = 200_000
#: Joint-steps a job may need (about 2 h of one core, 1 h on two, at a microsecond each).
MAX_JOB_JOINT_STEPS = 7_000_000_000


def planned_evaluations(body: TuningJobRequest) -> int:
    """The plan evaluations a job may need: every individual of every generation (and the initial
    population) on every task, for each phase (the DLS baseline and the bounded inverse, if asked)."""
    return body.ga.population * (body.ga.generations + 1) * len(body.tasks) * len(body.phases())


def samples_of(body: TuningJobRequest) -> int:
    """Robots each parameter set is planned on: the uncertainty's samples, or 1."""
    return body.uncertainty.samples if body.uncertainty is not None else 1


def planned_joint_steps(body: TuningJobRequest, problems: Sequence[TuningProblem], model: RobotModel) -> int:
    """The work a job may need in joint-steps: (population x (generations + 1), plus the
    refinement's most plans) x the plan-steps of its tasks (on each sampled robot) x joints, for
    each phase."""
    return sum(
        (body.ga.population * (body.ga.generations + 1) + (max_evaluations(len(p.bounds)) if body.refine else 0))
        * p.plan_steps()
        * model.n_joints
        for p in problems
    )


#: What in a request brings each phase of :meth:`TuningJobRequest.phases` (by its role).
PHASE_CAUSES = {
    "tuned": "the method tuned",
    "dls_baseline": "compare_with_dls",
    "bounded_baseline": "compare_with_bounded",
    "nominal_tuned": "uncertainty",
}


def check(model: RobotModel, body: TuningJobRequest) -> list[TuningProblem]:
    """Everything the GA would refuse, checked up front so that a bad job is a 422, not a
    failure; the job's engine problems (one per phase)."""
    phases = [PHASE_CAUSES[role] for _, role, _ in body.phases()]
    twice = f" * {len(phases)} (phases: {', '.join(phases)})" if len(phases) > 1 else ""
    samples = samples_of(body)
    sampled = f" * {samples} (uncertainty.samples)" if samples > 1 else ""
    # a robust job's excess is its samples' fault: the error names them
    where = ["body", "uncertainty", "samples"] if samples > 1 else ["body", "ga"]
    evaluations = planned_evaluations(body)
    if evaluations > MAX_PLAN_EVALUATIONS:
        msg = f"population * (generations + 1) * tasks{twice} = {evaluations} plan evaluations, at most {MAX_PLAN_EVALUATIONS}"
        raise ApiValidationError.at(["body", "ga"], msg)
    problems = body.problems(model)
    work = planned_joint_steps(body, problems, model)  # plan_steps() counts the samples
    if work > MAX_JOB_JOINT_STEPS:
        steps = problems[0].plan_steps()
        msg = (
            f"population * (generations + 1){twice} * plan-steps of the tasks{sampled} ({steps}) * joints ({model.n_joints}) "
            f"= {work:.3g} joint-steps, at most {MAX_JOB_JOINT_STEPS:.3g} per job (about a microsecond each: "
            f"{work * 1e-6 / 3600:.1g} h of one core): use fewer generations, a smaller population, fewer or "
            "shorter tasks, or a coarser dt_s"
        )
        raise ApiValidationError.at(where, msg)
    return problems


def fingerprint(body: TuningJobRequest) -> str:
    """SHA-256 of the validated body in a canonical form (sorted keys, defaults filled in), so
    the same request written differently has the same fingerprint."""
    return hashlib.sha256(jsonio.dumps_sorted(body.stored())).hexdigest()


def links(job_id: str) -> JobLinks:
    base = f"/v1/tuning-jobs/{job_id}"
    return JobLinks.model_validate(
        {
            "self": base,
            "result": f"{base}/result",
            "events": f"{base}/events",
            "convergence_figure": f"{base}/figures/convergence",
        }
    )


def phases(request: dict[str, Any], rows: Sequence[JobGeneration]) -> list[JobPhase]:
    """The GA runs of a job (its method, then the DLS baseline and the bounded inverse if asked) with their history
    (the rows of the job's current attempt)."""
    method = str(request.get("method", "adaptive"))
    generations = int((request.get("ga") or {}).get("generations", 50))
    roles: list[tuple[str, PhaseRole]] = [(method, "tuned")]
    if request.get("compare_with_dls", True):
        roles.append(("dls", "dls_baseline"))
    if request.get("compare_with_bounded", False) and method != "bounded":
        roles.append(("bounded", "bounded_baseline"))
    if request.get("uncertainty") is not None:
        roles.append((method, "nominal_tuned"))
    by_role: dict[str, list[HistoryRecord]] = {}
    for row in rows:
        stage: Stage = "refine" if row.stage == "refine" else "ga"
        record = HistoryRecord(generation=row.generation, best=row.best, mean=row.mean, feasible=row.feasible, stage=stage)
        by_role.setdefault(row.role, []).append(record)
    return [
        JobPhase(
            name=name,
            role=role,
            generations=generations,
            completed=max((r.generation for r in by_role.get(role, []) if r.stage == "ga"), default=0),
            history=by_role.get(role, []),
        )
        for name, role in roles
    ]


def attempt_of(job: TuningJob) -> int:
    """The attempt whose history the job shows: the one its progress says (the current one)."""
    return int((job.progress or {}).get("attempt", job.attempts))


def history(session: Session, jobs: Sequence[TuningJob], after: int = 0) -> dict[str, list[JobGeneration]]:
    """The generation rows of each job's current attempt with ``seq > after``, in order (one query)."""
    if not jobs:
        return {}
    wanted = {job.id: attempt_of(job) for job in jobs}
    rows = session.scalars(
        select(JobGeneration)
        .where(JobGeneration.job_id.in_(wanted), JobGeneration.seq > after)
        .order_by(JobGeneration.job_id, JobGeneration.seq)
    ).all()
    out: dict[str, list[JobGeneration]] = {job_id: [] for job_id in wanted}
    for row in rows:
        if row.attempt == wanted[row.job_id]:
            out[row.job_id].append(row)
    return out


def view(job: TuningJob, rows: Sequence[JobGeneration]) -> TuningJobOut:
    stored = dict(job.progress or {})
    job_phases = phases(job.request, rows)
    progress = {
        **stored,
        "generation": sum(p.completed for p in job_phases),
        "generations": sum(p.generations for p in job_phases),
        "evaluations": stored.get("evaluations", 0),
    }
    return TuningJobOut(
        id=job.id,
        status=job.status,  # type: ignore[arg-type]
        robot_id=job.robot_id,
        method=job.request.get("method", "adaptive"),
        progress=JobProgress(**progress, phases=job_phases),
        attempts=job.attempts,
        worker_id=job.worker_id,
        max_attempts=job.max_attempts,
        cancel_requested=job.cancel_requested,
        error=job.error,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        links=links(job.id),
    )


def load(session: Session, job_id: str) -> TuningJob:
    return rows.load(session, TuningJob, job_id, "tuning job")


def get(session: Session, job_id: str) -> TuningJobOut:
    job = load(session, job_id)
    return view(job, history(session, [job])[job.id])


def listing(session: Session, status: str | None, limit: int, offset: int) -> TuningJobList:
    where = [TuningJob.status == status] if status else []
    total = session.scalar(select(func.count()).select_from(TuningJob).where(*where)) or 0
    jobs = session.scalars(
        select(TuningJob).where(*where).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(limit).offset(offset)
    ).all()
    rows = history(session, jobs)
    return TuningJobList(items=[view(j, rows[j.id]) for j in jobs], total=total)


def _replayed(session: Session, job: TuningJob, key: str, digest: str) -> TuningJobOut:
    """The answer to a retry: the first job, unless the key came with another body (422)."""
    if job.idempotency_fingerprint is not None and job.idempotency_fingerprint != digest:
        msg = f"the Idempotency-Key {key!r} was used for a different request body (job {job.id}); use a new key"
        raise ApiValidationError.at(["header", "Idempotency-Key"], msg)
    return view(job, history(session, [job])[job.id])


def submit(db: Database, settings: Settings, body: TuningJobRequest, idempotency_key: str | None) -> TuningJobOut:
    """Queue a job (committed before the answer goes out: a client's next request sees it)."""
    digest = fingerprint(body)
    with db.session() as session:
        if idempotency_key is not None:
            existing = session.scalar(select(TuningJob).where(TuningJob.idempotency_key == idempotency_key))
            if existing is not None:
                return _replayed(session, existing, idempotency_key, digest)
        robot_id, model = robots.resolve(session, body.robot_id, body.robot)
        with meshes.hulls(session):
            check(model, body)
        check_quota(session, settings.storage_quota_bytes, len(jsonio.dumps(body.stored())))

    def insert(s: Session) -> TuningJob:
        # Counted inside the transaction that inserts, which submissions take one at a time
        # (Database.hold): two submissions never both see room for one more job.
        queued = s.scalar(select(func.count()).select_from(TuningJob).where(TuningJob.status == "queued")) or 0
        if queued >= settings.max_queued_jobs:
            raise TooManyRequestsError(
                f"{queued} tuning jobs are queued (at most {settings.max_queued_jobs}); retry later", RETRY_AFTER_S
            )
        job = TuningJob(
            status="queued",
            robot_id=robot_id,
            request=body.stored(),
            progress={
                "generation": 0,
                "generations": body.ga.generations * len(body.phases()),
                "evaluations": 0,
            },
            attempts=0,
            max_attempts=settings.job_max_attempts,
            cancel_requested=False,
            idempotency_key=idempotency_key,
            idempotency_fingerprint=digest if idempotency_key is not None else None,
        )
        s.add(job)
        return job

    try:
        job = db.write(insert, exclusive="tuning-job-submissions")  # its own transaction (retried if SQLite is locked)
    except IntegrityError:  # the same key raced in from another request
        with db.session() as s:
            existing = s.scalar(select(TuningJob).where(TuningJob.idempotency_key == idempotency_key))
            if existing is None:
                raise
            return _replayed(s, existing, idempotency_key or "", digest)
    return view(job, [])


def result(session: Session, job_id: str) -> TuningJobResult:
    """A job's result: a succeeded job's, or the best-so-far of a cancelled one (``status``
    ``cancelled``); a 409 for any other job, and for a job cancelled before its first generation."""
    job = load(session, job_id)
    if job.status not in ("succeeded", "cancelled") or job.result is None:
        extra = f": {job.error}" if job.error else ""
        if job.status == "cancelled":
            extra = ": it was cancelled before its GA finished a generation"
        raise ConflictError(
            f"tuning job {job_id!r} is {job.status}; a result exists once it succeeded, "
            f"or once it is cancelled after a generation{extra}"
        )
    return TuningJobResult.model_validate(job.result)


def cancel(db: Database, session: Session, job_id: str) -> TuningJobOut:
    job = load(session, job_id)
    if job.status in ("succeeded", "failed"):
        raise ConflictError(f"tuning job {job_id!r} already {job.status}")
    queue.request_cancel(db, job_id)
    session.expire_all()
    return get(session, job_id)


def delete(db: Database, job_id: str) -> None:
    """Delete a job (its generation rows with it); a queued or running one is cancelled first.
    Also on a full disk (:meth:`Database.freeing`)."""

    def run() -> None:
        with db.session() as session:
            running = load(session, job_id).status not in queue.TERMINAL
        if running:
            queue.request_cancel(db, job_id)
        db.write(lambda session: session.execute(sql_delete(TuningJob).where(TuningJob.id == job_id)))

    db.freeing(run)
