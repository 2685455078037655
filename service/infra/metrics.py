"""Prometheus metrics (prometheus-client), of two kinds:

- **Of the API processes** (counters, histograms and gauges): HTTP requests and their latency by
  method, route template and status (:class:`service.infra.observability.ObservabilityMiddleware`),
  plans computed by method and success, job event streams, and the process's own CPU, memory and
  file descriptors. One API process keeps them in its memory. Several API processes behind one
  port (``SPACEARM_API_PROCESSES``, :mod:`service.run`) share a directory
  (``PROMETHEUS_MULTIPROC_DIR``, prometheus-client's multiprocess mode): each process writes its
  values to files there, and whichever process answers a scrape sums them all, so one scrape
  target is the whole API (gauges: the sum over the living processes). The process's own CPU,
  memory and garbage-collector metrics are then left out: they would describe one process
  picked at random. API processes scraped as targets of their own instead (each on its own
  port) are summed in the queries (``sum by (route) (rate(spacearm_http_requests_total[5m]))``).
- **From the database, at scrape time** (:class:`DatabaseCollector`): tuning jobs by status, the
  age of the oldest queued job, the durations of recently finished jobs, and the heartbeat of
  every worker that holds a job. The queue lives in the database, so every API process reports the
  same, true numbers however many API processes and workers there are, and workers need no HTTP
  port of their own. Aggregate these with ``max``, not ``sum``.

Job durations are a *gauge histogram* (OpenMetrics ``gaugehistogram``; the Prometheus text format
writes it as a histogram with ``_gcount``/``_gsum`` gauges): the run times (``finished_at -
started_at`` of the last attempt) of the jobs submitted within :data:`JOB_WINDOW_S` that have
finished, by final status. A counter-histogram observed where jobs end would be wrong here: the
worker that ends a job has no metrics endpoint, and an API process that noticed it would count
it once per process, or not at all if no client asked. The window bounds the rows read per scrape
(they are found through the ``(status, created_at)`` index) and keeps the histogram independent
of how long finished jobs are kept.
"""

from __future__ import annotations

import logging
import os
import time
from collections import Counter as Tally
from collections.abc import Callable, Iterator
from datetime import timedelta

from prometheus_client import (
    GC_COLLECTOR,
    PLATFORM_COLLECTOR,
    PROCESS_COLLECTOR,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    disable_created_metrics,
)
from prometheus_client.core import GaugeHistogramMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.multiprocess import MultiProcessCollector, mark_process_dead
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString
from sqlalchemy import func, select

from service.infra.db import Database
from service.models import TuningJob, utcnow
from service.queue import TERMINAL

log = logging.getLogger("spacearm.api")

disable_created_metrics()  # the `_created` series double the output and no query here needs them

STATUSES = ("queued", "running", *TERMINAL)
#: Jobs submitted within this many seconds count in the duration histogram.
JOB_WINDOW_S = 24 * 3600.0
JOB_DURATION_BUCKETS = (1.0, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0, 3600.0, 7200.0, 21600.0)
REQUEST_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0)
PLAN_BUCKETS = (0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)

HTTP_REQUESTS = Counter(
    "spacearm_http_requests",
    "HTTP requests answered by the API processes behind this port, by method, route template and status",
    ["method", "route", "status"],
    registry=None,
)
HTTP_SECONDS = Histogram(
    "spacearm_http_request_duration_seconds",
    "time from a request's arrival to the end of its response body (s), by method, route template and status",
    ["method", "route", "status"],
    buckets=REQUEST_BUCKETS,
    registry=None,
)
HTTP_IN_PROGRESS = Gauge(
    "spacearm_http_requests_in_progress",
    "requests being handled by the API processes behind this port",
    registry=None,
    multiprocess_mode="livesum",
)
PLANS = Counter(
    "spacearm_plans_computed",
    "plans computed and stored by the API processes behind this port (POST /v1/plans, /v1/plans/shortest-duration), "
    "by method and success",
    ["method", "success"],
    registry=None,
)
PLAN_SECONDS = Histogram(
    "spacearm_plan_compute_seconds",
    "engine time of a stored plan (planning and replay, without HTTP and database) (s), by method",
    ["method"],
    buckets=PLAN_BUCKETS,
    registry=None,
)
EVENT_STREAMS_OPEN = Gauge(
    "spacearm_event_streams_open",
    "job event streams open in the API processes behind this port",
    registry=None,
    multiprocess_mode="livesum",
)
EVENT_STREAMS_REFUSED = Counter(
    "spacearm_event_streams_refused",
    "job event streams refused with 503 by the API processes behind this port (SPACEARM_MAX_EVENT_STREAMS open already)",
    registry=None,
)
EVENT_STREAM_POLLS = Counter(
    "spacearm_event_stream_polls",
    "database reads of the job event streams of the API processes behind this port (one per job and process every 0.5 s, "
    "however many listen)",
    registry=None,
)
#: The per-process metrics (registered in every app's registry, see :func:`registry_for`).
PER_PROCESS: tuple[Collector, ...] = (
    HTTP_REQUESTS,
    HTTP_SECONDS,
    HTTP_IN_PROGRESS,
    PLANS,
    PLAN_SECONDS,
    EVENT_STREAMS_OPEN,
    EVENT_STREAMS_REFUSED,
    EVENT_STREAM_POLLS,
    PROCESS_COLLECTOR,
    PLATFORM_COLLECTOR,
    GC_COLLECTOR,
)


def count_plan(method: str, success: bool, elapsed_s: float) -> None:
    PLANS.labels(method, "true" if success else "false").inc()
    PLAN_SECONDS.labels(method).observe(elapsed_s)


class DatabaseCollector(Collector):
    """Queue, job-duration and worker-heartbeat metrics read from the database at every scrape
    (three indexed queries). A database that does not answer gives
    ``spacearm_metrics_database_up 0`` and no database metrics, never a failed scrape."""

    def __init__(self, database: Callable[[], Database | None]) -> None:
        self.database = database

    def collect(self) -> Iterator[Metric]:
        up = GaugeMetricFamily("spacearm_metrics_database_up", "1 if the database answered this scrape's queries")
        start = time.perf_counter()
        db = self.database()
        try:
            if db is None:
                raise RuntimeError("the API has not opened its database yet")
            families = self._read(db)
        except Exception as exc:  # a scrape reports the fault instead of failing
            log.warning("metrics: the database did not answer: %s: %s", type(exc).__name__, exc)
            if db is not None:
                db.recover(exc)
            up.add_metric([], 0.0)
            yield up
            return
        up.add_metric([], 1.0)
        yield up
        yield from families
        seconds = GaugeMetricFamily("spacearm_metrics_database_seconds", "time this scrape spent on its database queries (s)")
        seconds.add_metric([], time.perf_counter() - start)
        yield seconds

    def _read(self, db: Database) -> list[Metric]:
        now = utcnow()
        with db.session() as s:
            by_status = dict(s.execute(select(TuningJob.status, func.count()).group_by(TuningJob.status)).tuples().all())
            oldest = s.scalar(select(func.min(TuningJob.created_at)).where(TuningJob.status == "queued"))
            running = s.execute(
                select(TuningJob.lease_owner, TuningJob.updated_at, TuningJob.lease_expires_at).where(
                    TuningJob.status == "running"
                )
            ).all()
            finished = s.execute(
                select(TuningJob.status, TuningJob.started_at, TuningJob.finished_at).where(
                    TuningJob.status.in_(TERMINAL),
                    TuningJob.created_at >= now - timedelta(seconds=JOB_WINDOW_S),
                    TuningJob.started_at.is_not(None),
                    TuningJob.finished_at.is_not(None),
                )
            ).all()

        jobs = GaugeMetricFamily("spacearm_tuning_jobs", "tuning jobs in the database by status", labels=["status"])
        for status in sorted(set(STATUSES) | set(by_status)):
            jobs.add_metric([status], float(by_status.get(status, 0)))
        age = GaugeMetricFamily(
            "spacearm_tuning_jobs_oldest_queued_age_seconds", "how long the oldest queued job has waited (s); 0 with none queued"
        )
        age.add_metric([], max(0.0, (now - oldest).total_seconds()) if oldest is not None else 0.0)

        heartbeat = GaugeMetricFamily(
            "spacearm_worker_heartbeat_age_seconds",
            "seconds since a worker holding a job last renewed its lease or wrote progress, by worker (host:pid:id)",
            labels=["worker"],
        )
        expired = 0
        for owner, updated_at, lease_expires_at in running:
            heartbeat.add_metric([owner or "unknown"], max(0.0, (now - updated_at).total_seconds()))
            expired += lease_expires_at is not None and lease_expires_at < now
        busy = GaugeMetricFamily("spacearm_workers_busy", "workers holding a running job")
        busy.add_metric([], float(len({owner for owner, _, _ in running})))
        lost = GaugeMetricFamily(
            "spacearm_tuning_jobs_lease_expired", "running jobs whose lease has expired (their worker stopped responding)"
        )
        lost.add_metric([], float(expired))

        durations = GaugeHistogramMetricFamily(
            "spacearm_tuning_job_duration_seconds",
            f"run time of the jobs submitted in the last {JOB_WINDOW_S / 3600:g} h that have finished (s), by final status",
            labels=["status"],
        )
        by_final: dict[str, list[float]] = {status: [] for status in TERMINAL}
        for status, started_at, finished_at in finished:
            if started_at is not None and finished_at is not None:  # (selected so)
                by_final.setdefault(status, []).append(max(0.0, (finished_at - started_at).total_seconds()))
        for status, values in by_final.items():
            tally = Tally(next((b for b in JOB_DURATION_BUCKETS if v <= b), float("inf")) for v in values)
            buckets, cumulative = [], 0
            for bound in (*JOB_DURATION_BUCKETS, float("inf")):
                cumulative += tally.get(bound, 0)
                buckets.append((floatToGoString(bound), float(cumulative)))
            durations.add_metric([status], buckets, gsum_value=sum(values))
        return [jobs, age, heartbeat, busy, lost, durations]


#: The environment variable that puts prometheus-client in multiprocess mode (read at its import).
MULTIPROCESS_DIR = "PROMETHEUS_MULTIPROC_DIR"


def shared_dir() -> str | None:
    """The directory the API processes share their metrics in, or None (one process)."""
    return os.environ.get(MULTIPROCESS_DIR) or None


def registry_for(database: Callable[[], Database | None]) -> CollectorRegistry:
    """An app's registry: the API's metrics (this process's, or every API process's summed from
    :func:`shared_dir`) and a :class:`DatabaseCollector`."""
    registry = CollectorRegistry(auto_describe=False)
    if shared_dir() is not None:
        MultiProcessCollector(registry)
    else:
        for collector in PER_PROCESS:
            registry.register(collector)
    registry.register(DatabaseCollector(database))
    return registry


def process_exited(pid: int) -> None:
    """Drop an API process's live gauges from the shared directory (as it stops)."""
    if shared_dir() is not None:
        mark_process_dead(pid)
