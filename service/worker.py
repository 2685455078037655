"""The worker: polls the queue, runs one job at a time. SIGTERM/SIGINT stop it gracefully: the
running job is stopped within a second and put back in the queue. Database faults never end
the worker: it backs off and tries again (and gives a running job back, see
:mod:`service.jobs`)."""

from __future__ import annotations

import logging
import os
import random
import signal
import socket
import threading
import uuid
from typing import Any

from sqlalchemy.engine import make_url

from engine import warm_up
from engine.tuning import MapFn, dask_map
from service import queue
from service.infra.collector import resume_collector
from service.infra.db import Database, is_database_fault, unavailable_reason
from service.infra.logs import JOB_ID
from service.infra.settings import Settings
from service.usecases.robots import seed_presets
from service.usecases.tuning_run import run_job

log = logging.getLogger("spacearm.worker")

MAX_BACKOFF_S = 30.0  # longest wait between tries while the database is unavailable


def worker_id() -> str:
    return f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def run_worker(
    settings: Settings, *, once: bool = False, shutdown: threading.Event | None = None, freeze_heap: bool = False
) -> int:
    """Poll loop. Returns the number of jobs processed. ``freeze_heap`` (``spacearm worker``, a
    process of its own): once the kernels are in, keep the start-up's objects out of full garbage
    collections and turn the collector on (:mod:`service.infra.collector`: it was off for the
    start-up)."""
    stop = shutdown or threading.Event()
    if shutdown is None and threading.current_thread() is threading.main_thread():

        def _handle(signum: int, _frame: Any) -> None:
            log.info("signal %s: stopping after the current generation", signum)
            stop.set()

        signal.signal(signal.SIGTERM, _handle)
        signal.signal(signal.SIGINT, _handle)

    seconds = warm_up()  # load (or compile) the kernels before claiming a job
    log.info("engine kernels ready in %.1f s", seconds)
    if freeze_heap:
        resume_collector()
    if stop.is_set():  # a signal during the warm-up: it said it was stopping, so no polling line
        log.info("worker stopped before it polled")
        return 0
    db = Database(settings.database_url, settings.sqlite_busy_timeout_ms)
    me = worker_id()
    dask_client = None
    map_fn: MapFn = map
    chunks = 1
    if settings.dask_scheduler:
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise SystemExit("SPACEARM_DASK_SCHEDULER is set but Dask is not installed: pip install 'spacearm[dask]'") from exc
        dask_client = Client(settings.dask_scheduler)
        map_fn, chunks = dask_map(dask_client), settings.dask_chunks
        log.info("GA evaluation spread over the Dask cluster at %s in %d chunks", settings.dask_scheduler, chunks)
    url = make_url(settings.database_url).render_as_string(hide_password=True)
    log.info("worker %s polling %s every %.2f s", me, url, settings.worker_poll_seconds)
    processed = 0
    seeded = False
    backoff = 0.0
    try:
        while not stop.is_set():
            try:
                if not seeded:
                    seed_presets(db)
                    seeded = True
                claim = queue.claim(db, me, settings.job_lease_seconds)
            except Exception as exc:  # a database fault: wait it out instead of exiting
                if not is_database_fault(exc):
                    raise
                db.recover(exc)
                backoff = min(max(2.0 * backoff, settings.worker_poll_seconds), MAX_BACKOFF_S)
                log.warning("the database is unavailable (%s); retrying in %.1f s", unavailable_reason(exc), backoff)
                stop.wait(backoff * (0.5 + random.random()))
                continue
            backoff = 0.0
            if claim is None:
                if once:
                    break
                stop.wait(settings.worker_poll_seconds)
                continue
            token = JOB_ID.set(claim.job_id)  # every log line of the job carries its id
            try:
                log.info("job %s claimed (attempt %d)", claim.job_id, claim.attempts)
                outcome = run_job(db, claim, settings.job_lease_seconds, stop, map_fn=map_fn, chunks=chunks)
                log.info("job %s: %s", claim.job_id, outcome)
            finally:
                JOB_ID.reset(token)
            processed += 1
            if once:
                break
    finally:
        if dask_client is not None:
            dask_client.close()
        db.dispose()
    return processed
