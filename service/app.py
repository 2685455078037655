"""The FastAPI application."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from service import errors, security
from service.db import Database
from service.migrate import seed_presets
from service.routers import figures, health, plans, robots, tasks, tuning, web
from service.settings import Settings

DESCRIPTION = """
Singularity-robust Cartesian path planning for free-floating space robots.

* SI units everywhere; angles are in **degrees only in fields whose name ends in `_deg`**
  (or `_deg_s`), radians elsewhere (`*_rad`). Quaternions are `[w, x, y, z]`.
* Plans are synchronous (`POST /v1/plans`); GA tuning jobs are asynchronous
  (`POST /v1/tuning-jobs`, then poll `GET /v1/tuning-jobs/{job_id}`).
* Errors are RFC 9457 problem details (`application/problem+json`).
"""

TAGS = [
    {"name": "robots", "description": "Robot parameter sets (schema of robot-table1.yaml) and the generalized Jacobian"},
    {"name": "tasks", "description": "Task presets; `paper-line` is the paper's detection line"},
    {"name": "plans", "description": "Synchronous Cartesian plans with a robust inverse"},
    {"name": "tuning", "description": "Asynchronous GA tuning jobs of the damping parameters"},
    {"name": "health", "description": "Liveness and readiness"},
]


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        db = Database(settings.database_url, settings.sqlite_busy_timeout_ms)
        app.state.db = db
        app.state.settings = settings
        with contextlib.suppress(Exception):  # not migrated yet: /readyz says so
            seed_presets(db)
        yield
        db.dispose()

    app = FastAPI(title="spacearm", version="0.1.0", description=DESCRIPTION, openapi_tags=TAGS, lifespan=lifespan)
    errors.install(app)
    security.install(app, settings)
    errors.problem_openapi(app)
    for module in (health, robots, tasks, plans, tuning, figures, web):
        app.include_router(module.router)
    return app
