"""The FastAPI application."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import threading
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import anyio
import httpx
from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

import engine
from engine.kernels.jit import park_linking_modules
from service import errors, openapi
from service.infra import observability, security
from service.infra.admission import INLINE_MAX_COST, Admission
from service.infra.checkpoint import Checkpointer
from service.infra.collector import resume_collector
from service.infra.db import Database
from service.infra.metrics import process_exited
from service.infra.ratelimit import AddressLimiter
from service.infra.retention import Sweeper
from service.infra.settings import Settings
from service.routers import (
    docs,
    figures,
    health,
    job_events,
    landscapes,
    meshes,
    metrics,
    plans,
    robots,
    shortest,
    tasks,
    tuning,
    web,
)
from service.run import notify_ready
from service.usecases.job_events import JobFeeds
from service.usecases.plans import rehearse
from service.usecases.robots import seed_presets

DESCRIPTION = """
Singularity-robust Cartesian path planning for free-floating space robots.

* SI units everywhere; angles are in **degrees only in fields whose name ends in `_deg`**
  (or `_deg_s`), radians elsewhere (`*_rad`). Quaternions are `[w, x, y, z]`. Joint positions come
  in index-aligned lists per unit: revolute joints in `..._deg`, prismatic joints in `..._m`
  (null at the joints of the other type).
* Plans are synchronous (`POST /v1/plans`); GA tuning jobs are asynchronous
  (`POST /v1/tuning-jobs`, then poll `GET /v1/tuning-jobs/{job_id}`).
* Errors are RFC 9457 problem details (`application/problem+json`).
"""

TAGS = [
    {
        "name": "robots",
        "description": "Robots: parameter sets (the schema of engine/data/table1_robot.json) or URDF files, their URDF, the GJM",
    },
    {"name": "meshes", "description": "Meshes (STL, OBJ) whose convex hulls are obstacles of task scenes"},
    {"name": "tasks", "description": "Task presets; `paper-line` is the paper's detection line"},
    {"name": "plans", "description": "Synchronous Cartesian plans with a robust inverse"},
    {"name": "tuning", "description": "Asynchronous GA tuning jobs of the damping parameters, with live events"},
    {"name": "landscapes", "description": "Objective landscapes: B over a grid of two parameters of a method"},
    {"name": "health", "description": "Liveness and readiness"},
]


log = logging.getLogger("spacearm.api")
logging.getLogger("httpx").setLevel(logging.WARNING)  # the in-process requests are not news
STATIC = Path(__file__).resolve().parent / "static"

#: Requests that reach every router without changing anything (see :meth:`Kernels._visit_routers`).
#: An id that no stored row has (ids are 32 hex digits: other text would not reach the routes).
_NO_ID = "0" * 32
WARM_UP_PATHS = (
    f"/v1/plans/{_NO_ID}",
    f"/v1/plans/{_NO_ID}/figures/warm-up",  # an unknown figure: a 404 before the figures' admission
    "/v1/robots/warm-up",
    "/v1/meshes",
    "/v1/task-presets",
    f"/v1/tuning-jobs/{_NO_ID}",
    f"/plans/{_NO_ID}",
)


class Kernels:
    """Loads (or compiles) the engine's kernels in a background thread at start-up, then
    rehearses a plan request (rolled back): liveness answers at once, readiness once the kernels
    are in (see :func:`engine.warm_up`), so the first request runs at the steady-state speed.

    ``freeze_heap``: last, keep the start-up's objects out of full garbage collections and turn
    the collector on (:mod:`service.infra.collector`: ``spacearm serve`` turned it off for the
    start-up); only in a process of its own, not in one that holds tests."""

    def __init__(self, app: FastAPI, db: Database, settings: Settings, freeze_heap: bool = False) -> None:
        self.app = app
        self.db = db
        self.settings = settings
        self.freeze_heap = freeze_heap
        self.ready = threading.Event()
        self.error: str | None = None
        self.seconds: float | None = None

    def start(self) -> None:
        threading.Thread(target=self._load, name="kernel-warm-up", daemon=True).start()

    def _load(self) -> None:
        start = time.perf_counter()
        try:
            engine.warm_up()
            self.seconds = time.perf_counter() - start
            log.info("engine kernels ready in %.1f s", self.seconds)
        except Exception as exc:  # reported by /readyz; plans would fail the same way
            self.error = f"{type(exc).__name__}: {exc}"
            log.exception("loading the engine kernels failed")
            self._resume_collector()
            self.ready.set()
            notify_ready(f"loading the engine kernels failed: {self.error}")
            return
        try:
            rehearse(self.db, self.settings)
            asyncio.run(self._visit_routers())
        except Exception as exc:  # e.g. not migrated yet: /readyz reports the database itself
            log.info("request rehearsal skipped: %s: %s", type(exc).__name__, exc)
        finally:
            self._resume_collector()
            park_linking_modules()  # and what the rehearsal freed goes back to the system
            self.ready.set()
            notify_ready("ready")

    def _resume_collector(self) -> None:
        if self.freeze_heap:
            resume_collector()

    async def _visit_routers(self) -> None:
        """FastAPI prepares each router's routes on the first request that reaches it; send each
        one a request that changes nothing (unknown ids answer 404), in process (not counted in
        the metrics)."""
        observability.UNCOUNTED.set(True)
        keys = self.settings.keys()
        headers = {"authorization": f"Bearer {keys[0]}"} if keys else {}
        transport = httpx.ASGITransport(app=self.app)
        async with httpx.AsyncClient(
            transport=transport, base_url=f"http://{self.settings.internal_host()}", headers=headers
        ) as client:
            for path in WARM_UP_PATHS:
                response = await client.get(path)
                if response.status_code not in (200, 404):  # not prepared: the first real request pays
                    log.warning("start-up rehearsal: GET %s answered %d", path, response.status_code)

    @property
    def state(self) -> str:
        if not self.ready.is_set():
            return "loading"
        return "ok" if self.error is None else f"failed: {self.error}"


def create_app(settings: Settings | None = None, *, freeze_heap: bool = False) -> FastAPI:
    """The API (``freeze_heap``: see :class:`Kernels`; ``spacearm serve`` sets it)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # The thread pool and the database pool are sized together (a blocking handler never
        # waits for a connection); plans and figure renders are admitted a few at a time.
        anyio.to_thread.current_default_thread_limiter().total_tokens = settings.api_threads
        db = Database(
            settings.database_url,
            settings.sqlite_busy_timeout_ms,
            pool_size=settings.pool_size(),
            max_overflow=0,
            pool_timeout_s=settings.db_pool_timeout_s,
            background_checkpoints=True,  # the Checkpointer below: no fsync on a request's commit
        )
        app.state.db = db
        # readiness has a connection and a thread of its own: it answers however busy the API is
        app.state.health_db = Database(
            settings.database_url, settings.sqlite_busy_timeout_ms, pool_size=1, max_overflow=1, pool_timeout_s=1.0
        )
        app.state.health_limiter = anyio.CapacityLimiter(2)
        app.state.settings = settings
        slots = settings.plan_slots()
        # Cheap plans run on the event loop (INLINE_MAX_COST) with SQLite, and only when a database
        # connection is left for the loop beside the threads' and the retention sweep's:
        # PostgreSQL's round trips, and its connection timeouts when the server is gone, stay off
        # the loop.
        inline = INLINE_MAX_COST if db.path is not None and settings.pool_size() > settings.api_threads + 1 else 0.0
        app.state.plan_admission = Admission("plans", slots, settings.plan_queue, settings.plan_queue_timeout_s, inline)
        app.state.figure_admission = Admission("figure renders", slots, 4 * slots, settings.plan_queue_timeout_s)
        app.state.job_feeds = JobFeeds(db, job_events.POLL_S, settings.max_event_streams)
        app.state.login_limiter = AddressLimiter("login", settings.login_attempts_per_minute)
        app.state.kernels = Kernels(app, db, settings, freeze_heap)
        app.state.kernels.start()
        with contextlib.suppress(Exception):  # not migrated yet: /readyz says so
            seed_presets(db)
        sweeper = Sweeper(db, settings.retention_days, settings.retention_sweep_s) if settings.retention_days else None
        if sweeper is not None:
            sweeper.start()
        checkpointer = Checkpointer(db.path) if db.path is not None else None
        if checkpointer is not None:
            checkpointer.start()
        try:
            yield
        finally:
            try:
                if sweeper is not None:
                    sweeper.stop()
                if checkpointer is not None:
                    checkpointer.stop()
                db.dispose()
                app.state.health_db.dispose()
            finally:
                process_exited(os.getpid())  # its live gauges leave the shared metrics

    # /docs and /redoc are ours (service.routers.docs): offline assets, no inline script
    app = FastAPI(
        title="spacearm",
        version="0.1.0",
        description=DESCRIPTION,
        openapi_tags=TAGS,
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
    )
    errors.install(app)
    security.install(app, settings)
    openapi.install(app, auth_required=bool(settings.keys()))
    observability.install(app)
    app.include_router(metrics.make_router(auth_required=bool(settings.keys())))
    for module in (health, robots, meshes, tasks, plans, shortest, tuning, job_events, landscapes, figures, web, docs):
        app.include_router(module.router)
    app.mount(docs.ASSETS_URL, docs.assets(), name="docs-assets")
    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    return app
