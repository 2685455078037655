"""Asynchronous GA tuning jobs, in the style of OGC API - Processes: submit (202 + Location),
poll, read the result, cancel. Workers run them (``spacearm worker``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Query, Request, Response, status

from service.deps import DbDep, JobId, JsonAnswer, JsonBody, Limit, Offset, SessionDep, SessionRoute, SettingsDep
from service.errors import responses
from service.schemas.common import JobStatus
from service.schemas.tuning import TuningJobList, TuningJobOut, TuningJobRequest, TuningJobResult
from service.usecases import tuning_jobs
from service.usecases.tuning_jobs import MAX_JOB_JOINT_STEPS

router = APIRouter(prefix="/v1/tuning-jobs", tags=["tuning"], route_class=SessionRoute)


@router.post(
    "",
    operation_id="create_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Submit a GA tuning job (asynchronous)",
    description="Returns 202 with `Location` of the job. Send `Idempotency-Key` to make retries safe: "
    "the same key with the same body returns the same job; the same key with another body is a 422. "
    "A job is bounded by its work: at most 200,000 plan evaluations "
    "(population * (generations + 1) * tasks, once more for each of `compare_with_dls`, `compare_with_bounded` and "
    "`uncertainty` (the nominal GA); the refinement's plans not counted) and at most "
    f"{MAX_JOB_JOINT_STEPS:.2g} joint-steps (the same times the plan-steps of the tasks times the robot's joints; "
    "about a microsecond each); 429 with `Retry-After` when `SPACEARM_MAX_QUEUED_JOBS` jobs are already queued.",
    responses=responses(404, 406, 415, 422),
    dependencies=[JsonAnswer, JsonBody],
)
def create_tuning_job(
    body: TuningJobRequest,
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
    job = tuning_jobs.submit(request.app.state.db, settings, body, idempotency_key)
    response.headers["Location"] = f"/v1/tuning-jobs/{job.id}"
    return job


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
    return tuning_jobs.listing(session, status_, limit, offset)


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
    return tuning_jobs.get(session, job_id)


@router.get(
    "/{job_id:id}/result",
    operation_id="get_tuning_job_result",
    response_model=TuningJobResult,
    response_model_by_alias=True,
    summary="Result of a succeeded tuning job, or the best-so-far of a cancelled one (409 otherwise)",
    description="The tuned parameters, their B and metrics per task, the GA's history per generation and, with "
    "`compare_with_dls`, the tuned DLS baseline and the improvement over it; with `compare_with_bounded`, the "
    "tuned bounded inverse (the third row). `status` says whether the GA ran every "
    "generation (`succeeded`) or the job was cancelled (`cancelled`: the best parameters found by then, `message` "
    "says how far each GA got; the baseline is null if its GA had not finished a generation). A 409 while the job is "
    "queued or running, once it failed, and for a job cancelled before its GA finished a generation (`detail` says "
    "the job's status and error).",
    responses=responses(404, 409),
)
def get_tuning_job_result(job_id: JobId, session: SessionDep) -> TuningJobResult:
    return tuning_jobs.result(session, job_id)


@router.post(
    "/{job_id:id}/cancel",
    operation_id="cancel_tuning_job",
    response_model=TuningJobOut,
    status_code=status.HTTP_202_ACCEPTED,
    summary="Cancel a tuning job (a running one stops within a second or two and keeps its best-so-far result)",
    description="A queued job is cancelled at once; a running one stops within a second or two (the worker looks for "
    "the request every second, inside a generation) and stores the best parameters found so far as its result "
    "(`GET .../result`, `status` `cancelled`). 202 with the job (`cancel_requested` true); a job that "
    "already succeeded or failed is a 409.",
    responses=responses(404, 409),
)
def cancel_tuning_job(job_id: JobId, session: SessionDep, request: Request) -> TuningJobOut:
    return tuning_jobs.cancel(request.app.state.db, session, job_id)


@router.delete(
    "/{job_id:id}",
    operation_id="delete_tuning_job",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a tuning job (a queued or running one is cancelled first)",
    description="204 once deleted; 404 for an unknown id. A running job's worker notices within about a second "
    "that the job is gone and stops its GA.",
    responses=responses(404),
)
def delete_tuning_job(job_id: JobId, db: DbDep) -> Response:
    tuning_jobs.delete(db, job_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
