"""Asynchronous GA tuning jobs, in the style of OGC API - Processes: submit (202 + Location),
poll, read the result, cancel. Workers run them (``spacearm worker``)."""

from __future__ import annotations

import hashlib
from typing import Annotated, Any

from fastapi import APIRouter, Header, Query, Request, Response, status
from sqlalchemy import delete, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from service import queue
from service.convert import resolve_robot
from service.deps import JobId, Limit, Offset, SessionDep, SessionRoute, SettingsDep, load_row
from service.errors import ApiValidationError, ConflictError, TooManyRequestsError, responses
from service.infra import jsonio
from service.infra.db import Database
from service.infra.quota import check_quota
from service.jobs import MAX_JOB_JOINT_STEPS, validate_request
from service.models import TuningJob
from service.schemas.common import JobStatus
from service.schemas.tuning import (
    GASettings,
    HistoryRecord,
    JobLinks,
    JobPhase,
    JobProgress,
    PhaseRole,
    TuningJobList,
    TuningJobOut,
    TuningJobRequest,
    TuningJobResult,
)

router = APIRouter(prefix="/v1/tuning-jobs", tags=["tuning"], route_class=SessionRoute)

RETRY_AFTER_S = 10  # Retry-After of a 429 (the queue is full)


def body_fingerprint(body: TuningJobRequest) -> str:
    """SHA-256 of the validated body in a canonical form (sorted keys, defaults filled in), so
    the same request written differently has the same fingerprint."""
    return hashlib.sha256(jsonio.dumps_sorted(body.stored())).hexdigest()


def replayed(job: TuningJob, key: str, fingerprint: str, response: Response) -> TuningJobOut:
    """The answer to a retry: the first job, unless the key came with another body (422)."""
    if job.idempotency_fingerprint is not None and job.idempotency_fingerprint != fingerprint:
        msg = f"the Idempotency-Key {key!r} was used for a different request body (job {job.id}); use a new key"
        raise ApiValidationError(msg, [{"loc": ["header", "Idempotency-Key"], "msg": msg}])
    response.headers["Location"] = f"/v1/tuning-jobs/{job.id}"
    return job_out(job)


def _role(row: dict[str, Any], method: str, restarts: int) -> str:
    """The phase role of a history row; rows of older workers have no role: they go by name
    (and, when the tuned method is DLS itself, by the restart of the generations at 0)."""
    if "role" in row:
        return str(row["role"])
    if row.get("phase") == "dls" and (method != "dls" or restarts > 1):
        return "dls_baseline"
    return "tuned"


def job_phases(request: dict[str, Any], history: list[dict[str, Any]]) -> list[JobPhase]:
    """The GA runs of a job (its method, then the DLS baseline if asked) with their history."""
    method = str(request.get("method", "adaptive"))
    generations = int((request.get("ga") or {}).get("generations", GASettings().generations))
    roles: list[tuple[str, PhaseRole]] = [(method, "tuned")]
    if request.get("compare_with_dls", True):
        roles.append(("dls", "dls_baseline"))
    by_role: dict[str, list[HistoryRecord]] = {}
    restarts = 0
    for row in history:
        restarts += row.get("generation") == 0
        record = HistoryRecord.model_validate({k: row.get(k) for k in ("generation", "best", "mean", "feasible")})
        by_role.setdefault(_role(row, method, restarts), []).append(record)
    return [
        JobPhase(
            name=name,  # type: ignore[arg-type]
            role=role,
            generations=generations,
            completed=max((r.generation for r in by_role.get(role, [])), default=0),
            history=by_role.get(role, []),
        )
        for name, role in roles
    ]


def job_links(job_id: str) -> JobLinks:
    base = f"/v1/tuning-jobs/{job_id}"
    return JobLinks.model_validate(
        {
            "self": base,
            "result": f"{base}/result",
            "events": f"{base}/events",
            "convergence_figure": f"{base}/figures/convergence",
        }
    )


def job_out(job: TuningJob) -> TuningJobOut:
    stored = dict(job.progress or {})
    phases = job_phases(job.request, stored.pop("history", None) or [])
    progress = {
        **stored,
        "generation": sum(p.completed for p in phases),
        "generations": sum(p.generations for p in phases),
        "evaluations": stored.get("evaluations", 0),
    }
    return TuningJobOut(
        id=job.id,
        status=job.status,  # type: ignore[arg-type]
        robot_id=job.robot_id,
        method=job.request.get("method", "adaptive"),
        progress=JobProgress(**progress, phases=phases),
        attempts=job.attempts,
        max_attempts=job.max_attempts,
        cancel_requested=job.cancel_requested,
        error=job.error,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
        links=job_links(job.id),
    )


@router.post(
    "",
    operation_id="create_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Submit a GA tuning job (asynchronous)",
    description="Returns 202 with `Location` of the job. Send `Idempotency-Key` to make retries safe: "
    "the same key with the same body returns the same job; the same key with another body is a 422. "
    "A job is bounded by its work: at most 200,000 plan evaluations "
    "(population * (generations + 1) * tasks, twice with `compare_with_dls`) and at most "
    f"{MAX_JOB_JOINT_STEPS:.2g} joint-steps (the same times the plan-steps of the tasks times the robot's joints; "
    "about a microsecond each); 429 with `Retry-After` when `SPACEARM_MAX_QUEUED_JOBS` jobs are already queued.",
    responses=responses(404, 422),
)
def create_tuning_job(
    body: TuningJobRequest,
    session: SessionDep,
    settings: SettingsDep,
    request: Request,
    response: Response,
    idempotency_key: Annotated[
        str | None,
        Header(
            alias="Idempotency-Key",
            min_length=1,
            max_length=255,
            pattern=r"^[\x20-\x7e]+$",
            description="1 to 255 printable ASCII characters; a retry with the same key and body returns the first job",
        ),
    ] = None,
) -> TuningJobOut:
    db: Database = request.app.state.db
    fingerprint = body_fingerprint(body)
    if idempotency_key is not None:
        existing = session.scalar(select(TuningJob).where(TuningJob.idempotency_key == idempotency_key))
        if existing is not None:
            return replayed(existing, idempotency_key, fingerprint, response)
    robot_id, model = resolve_robot(session, body.robot_id, body.robot)
    validate_request(model, body)
    queued = session.scalar(select(func.count()).select_from(TuningJob).where(TuningJob.status == "queued")) or 0
    if queued >= settings.max_queued_jobs:
        raise TooManyRequestsError(
            f"{queued} tuning jobs are queued (at most {settings.max_queued_jobs}); retry later", RETRY_AFTER_S
        )
    check_quota(session, settings.storage_quota_bytes, len(jsonio.dumps(body.stored())))
    session.close()  # the insert runs in its own transaction (retried if SQLite is locked)

    def insert(s: Session) -> TuningJob:
        job = TuningJob(
            status="queued",
            robot_id=robot_id,
            request=body.stored(),
            progress={
                "generation": 0,
                "generations": body.ga.generations * (2 if body.compare_with_dls else 1),
                "evaluations": 0,
            },
            attempts=0,
            max_attempts=settings.job_max_attempts,
            cancel_requested=False,
            idempotency_key=idempotency_key,
            idempotency_fingerprint=fingerprint if idempotency_key is not None else None,
        )
        s.add(job)
        return job

    try:
        job = db.write(insert)  # committed before the response goes out: a client's next request sees it
    except IntegrityError:  # the same key raced in from another request
        with db.session() as s:
            existing = s.scalar(select(TuningJob).where(TuningJob.idempotency_key == idempotency_key))
        if existing is None:
            raise
        return replayed(existing, idempotency_key or "", fingerprint, response)
    response.headers["Location"] = f"/v1/tuning-jobs/{job.id}"
    return job_out(job)


@router.get(
    "",
    operation_id="list_tuning_jobs",
    response_model=TuningJobList,
    summary="List tuning jobs",
    description="Tuning jobs, newest first, `limit` at a time from `offset`, optionally only those with `status`; "
    "`total` counts them all.",
    responses=responses(422),
)
def list_tuning_jobs(
    session: SessionDep,
    status_: Annotated[JobStatus | None, Query(alias="status", description="only the jobs with this status")] = None,
    limit: Limit = 50,
    offset: Offset = 0,
) -> TuningJobList:
    where = [TuningJob.status == status_] if status_ else []
    total = session.scalar(select(func.count()).select_from(TuningJob).where(*where)) or 0
    rows = session.scalars(
        select(TuningJob).where(*where).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(limit).offset(offset)
    ).all()
    return TuningJobList(items=[job_out(j) for j in rows], total=total)


def _load(session: SessionDep, job_id: JobId) -> TuningJob:
    return load_row(session, TuningJob, job_id, "tuning job")


@router.get(
    "/{job_id:id}",
    operation_id="get_tuning_job",
    response_model=TuningJobOut,
    summary="Get a tuning job",
    description="The job's status and progress (generation, evaluations, best B so far and its parameters); poll it "
    "until `status` is `succeeded`, `failed` or `cancelled`.",
    responses=responses(404),
)
def get_tuning_job(job_id: JobId, session: SessionDep) -> TuningJobOut:
    return job_out(_load(session, job_id))


@router.get(
    "/{job_id:id}/result",
    operation_id="get_tuning_job_result",
    response_model=TuningJobResult,
    response_model_by_alias=True,
    summary="Result of a succeeded tuning job (409 until then)",
    description="The tuned parameters, their B and metrics per task, the GA's history per generation and, with "
    "`compare_with_dls`, the tuned DLS baseline and the improvement over it. A 409 until the job has succeeded "
    "(its `detail` says the job's status and error).",
    responses=responses(404, 409),
)
def get_tuning_job_result(job_id: JobId, session: SessionDep) -> TuningJobResult:
    job = _load(session, job_id)
    if job.status != "succeeded" or job.result is None:
        extra = f": {job.error}" if job.error else ""
        raise ConflictError(f"tuning job {job_id!r} is {job.status}, the result exists once it succeeded{extra}")
    return TuningJobResult.model_validate(job.result)


@router.post(
    "/{job_id:id}/cancel",
    operation_id="cancel_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Cancel a tuning job (a running one stops after its current generation)",
    description="A queued job is cancelled at once; a running one stops within a second or two (the worker looks for "
    "the request every second, inside a generation). 202 with the job (`cancel_requested` true); a job that "
    "already succeeded or failed is a 409.",
    responses=responses(404, 409),
)
def cancel_tuning_job(job_id: JobId, session: SessionDep, request: Request) -> TuningJobOut:
    job = _load(session, job_id)
    if job.status in ("succeeded", "failed"):
        raise ConflictError(f"tuning job {job_id!r} already {job.status}")
    db: Database = request.app.state.db
    queue.request_cancel(db, job_id)
    session.expire_all()
    return job_out(_load(session, job_id))


@router.delete(
    "/{job_id:id}",
    operation_id="delete_tuning_job",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a tuning job (a queued or running one is cancelled first)",
    description="204 once deleted; 404 for an unknown id. A running job's worker notices within about a second "
    "that the job is gone and stops its GA.",
    responses=responses(404),
)
def delete_tuning_job(job_id: JobId, session: SessionDep, request: Request) -> Response:
    job = _load(session, job_id)
    running = job.status not in queue.TERMINAL
    session.rollback()  # end the read: SQLite cannot turn a read that another write overtook into a write
    if running:
        queue.request_cancel(request.app.state.db, job_id)
    session.execute(delete(TuningJob).where(TuningJob.id == job_id))
    return Response(status_code=status.HTTP_204_NO_CONTENT)
