"""Asynchronous GA tuning jobs, in the style of OGC API - Processes: submit (202 + Location),
poll, read the result, cancel. Workers run them (``spacearm worker``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response, status
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from service import queue
from service.convert import resolve_robot
from service.db import Database
from service.deps import SessionDep, SettingsDep
from service.errors import MAX_OFFSET, ConflictError, NotFoundError, TooManyRequestsError, responses
from service.jobs import validate_request
from service.models import TuningJob
from service.schemas import JobProgress, JobStatus, TuningJobList, TuningJobOut, TuningJobRequest, TuningJobResult

router = APIRouter(prefix="/v1/tuning-jobs", tags=["tuning"])

RETRY_AFTER_S = 10  # Retry-After of a 429 (the queue is full)


def job_out(job: TuningJob) -> TuningJobOut:
    progress = job.progress or {"generation": 0, "generations": 0, "evaluations": 0}
    return TuningJobOut(
        id=job.id,
        status=job.status,  # type: ignore[arg-type]
        robot_id=job.robot_id,
        method=str(job.request.get("method", "adaptive")),
        progress=JobProgress(**progress),
        attempts=job.attempts,
        max_attempts=job.max_attempts,
        cancel_requested=job.cancel_requested,
        error=job.error,
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
    )


@router.post(
    "",
    operation_id="create_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Submit a GA tuning job (asynchronous)",
    description="Returns 202 with `Location` of the job. Send `Idempotency-Key` to make retries safe: "
    "the same key returns the same job. At most 200,000 plan evaluations per job "
    "(population * (generations + 1) * tasks, twice with `compare_with_dls`); 429 with `Retry-After` "
    "when `SPACEARM_MAX_QUEUED_JOBS` jobs are already queued.",
    responses=responses(404, 422),
)
def create_tuning_job(
    body: TuningJobRequest,
    session: SessionDep,
    settings: SettingsDep,
    request: Request,
    response: Response,
    idempotency_key: Annotated[str | None, Header(alias="Idempotency-Key", max_length=200)] = None,
) -> TuningJobOut:
    db: Database = request.app.state.db
    if idempotency_key:
        existing = session.scalar(select(TuningJob).where(TuningJob.idempotency_key == idempotency_key))
        if existing is not None:
            response.headers["Location"] = f"/v1/tuning-jobs/{existing.id}"
            return job_out(existing)
    robot_id, model = resolve_robot(session, body.robot_id, body.robot)
    validate_request(model, body)
    queued = session.scalar(select(func.count()).select_from(TuningJob).where(TuningJob.status == "queued")) or 0
    if queued >= settings.max_queued_jobs:
        raise TooManyRequestsError(
            f"{queued} tuning jobs are queued (at most {settings.max_queued_jobs}); retry later", RETRY_AFTER_S
        )
    session.close()  # the insert runs in its own transaction (retried if SQLite is locked)

    def insert(s: Session) -> TuningJob:
        job = TuningJob(
            status="queued",
            robot_id=robot_id,
            request=body.model_dump(mode="json"),
            progress={
                "generation": 0,
                "generations": body.ga.generations * (2 if body.compare_with_dls else 1),
                "evaluations": 0,
            },
            attempts=0,
            max_attempts=settings.job_max_attempts,
            cancel_requested=False,
            idempotency_key=idempotency_key,
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
        response.headers["Location"] = f"/v1/tuning-jobs/{existing.id}"
        return job_out(existing)
    response.headers["Location"] = f"/v1/tuning-jobs/{job.id}"
    return job_out(job)


@router.get(
    "", operation_id="list_tuning_jobs", response_model=TuningJobList, summary="List tuning jobs", responses=responses(422)
)
def list_tuning_jobs(
    session: SessionDep,
    status_: Annotated[JobStatus | None, Query(alias="status")] = None,
    limit: int = Query(50, ge=1, le=500),
    offset: int = Query(0, ge=0, le=MAX_OFFSET),
) -> TuningJobList:
    where = [TuningJob.status == status_] if status_ else []
    total = session.scalar(select(func.count()).select_from(TuningJob).where(*where)) or 0
    rows = session.scalars(
        select(TuningJob).where(*where).order_by(TuningJob.created_at.desc(), TuningJob.id).limit(limit).offset(offset)
    ).all()
    return TuningJobList(items=[job_out(j) for j in rows], total=total)


def _load(session: SessionDep, job_id: str) -> TuningJob:
    job = session.get(TuningJob, job_id)
    if job is None:
        raise NotFoundError("tuning job", job_id)
    return job


@router.get(
    "/{job_id}", operation_id="get_tuning_job", response_model=TuningJobOut, summary="Get a tuning job", responses=responses(404)
)
def get_tuning_job(job_id: str, session: SessionDep) -> TuningJobOut:
    return job_out(_load(session, job_id))


@router.get(
    "/{job_id}/result",
    operation_id="get_tuning_job_result",
    response_model=TuningJobResult,
    response_model_by_alias=True,
    summary="Result of a succeeded tuning job (409 until then)",
    responses=responses(404, 409),
)
def get_tuning_job_result(job_id: str, session: SessionDep) -> TuningJobResult:
    job = _load(session, job_id)
    if job.status != "succeeded" or job.result is None:
        extra = f": {job.error}" if job.error else ""
        raise ConflictError(f"tuning job {job_id!r} is {job.status}, the result exists once it succeeded{extra}")
    return TuningJobResult.model_validate(job.result)


@router.post(
    "/{job_id}/cancel",
    operation_id="cancel_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Cancel a tuning job (a running one stops after its current generation)",
    responses=responses(404, 409),
)
def cancel_tuning_job(job_id: str, session: SessionDep, request: Request) -> TuningJobOut:
    job = _load(session, job_id)
    if job.status in ("succeeded", "failed"):
        raise ConflictError(f"tuning job {job_id!r} already {job.status}")
    db: Database = request.app.state.db
    queue.request_cancel(db, job_id)
    session.expire_all()
    return job_out(_load(session, job_id))
