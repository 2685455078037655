"""``GET /metrics``: Prometheus metrics (see :mod:`service.infra.metrics`) in the text format 0.0.4.
Outside ``/v1`` (it is not part of the versioned API), but behind the same bearer keys when
``SPACEARM_API_KEYS`` is set: it names workers (host and pid) and shows the traffic."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, Response
from prometheus_client import generate_latest

from service.openapi import BEARER

#: The classic text format: every name here is a legacy Prometheus name, which every Prometheus
#: version reads (prometheus-client's default, 1.0.0, would say so only to the newest).
CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"

DESCRIPTION = """Prometheus metrics of the API (text exposition format 0.0.4).

Of the API's traffic: `spacearm_http_requests_total` and `spacearm_http_request_duration_seconds`
by `method`, `route` (the path template) and `status`; `spacearm_plans_computed_total` by `method`
and `success`; `spacearm_plan_compute_seconds` by `method`. With one API process (the default)
they are that process's, with `process_*` and `python_*`; with several behind one port
(`spacearm run --api-processes N`) they are the sums over all of them, whichever process answers,
and `process_*` and `python_*` are left out.

From the database at each scrape (the same in every API process): `spacearm_tuning_jobs` by
`status`, `spacearm_tuning_jobs_oldest_queued_age_seconds`, `spacearm_tuning_job_duration_seconds`
(a gauge histogram of the run times of the jobs submitted in the last 24 h that have finished, by
final `status`), `spacearm_worker_heartbeat_age_seconds` by `worker`, `spacearm_workers_busy`,
`spacearm_tuning_jobs_lease_expired`, `spacearm_metrics_database_up`.

Needs a bearer key when `SPACEARM_API_KEYS` is set (as `/v1` does)."""


def make_router(auth_required: bool) -> APIRouter:
    router = APIRouter(tags=["health"])
    responses: dict[int | str, dict[str, Any]] = {
        200: {"description": "the metrics", "content": {"text/plain": {"schema": {"type": "string"}}}}
    }
    # With keys, the bearer scheme is required here as on /v1; without, the operation states no
    # requirement of its own (it is open, and a generator need not ask for an authenticated client).
    extra: dict[str, Any] = {}
    if auth_required:
        responses[401] = {"description": "missing or invalid API key"}
        extra["security"] = [{BEARER: []}]

    @router.get(
        "/metrics",
        operation_id="metrics",
        summary="Prometheus metrics: requests, plans, the job queue, job durations, worker heartbeats",
        description=DESCRIPTION,
        response_class=Response,
        responses=responses,
        openapi_extra=extra,
    )
    def metrics(request: Request) -> Response:
        return Response(generate_latest(request.app.state.metrics_registry), media_type=CONTENT_TYPE)

    return router
