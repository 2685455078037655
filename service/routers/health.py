"""Liveness and readiness. Both are ``async`` handlers: liveness touches nothing and never waits
behind plan work; readiness runs its database checks in a thread of its own small pool, on a
database connection of its own (see ``app.state.health_db``), with a time limit, so a saturated
API still reports promptly."""

from __future__ import annotations

import anyio
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service import openapi
from service.deps import SessionRoute
from service.schemas.health import Health
from service.usecases.health import check_database

router = APIRouter(tags=["health"], route_class=SessionRoute)

READY_TIMEOUT_S = 3.0


@router.get(
    "/healthz",
    operation_id="healthz",
    response_model=Health,
    response_model_exclude_none=True,
    summary="Liveness",
    description='Always `{"status": "ok"}` while the process serves requests; touches neither the kernels nor '
    "the database (use `/readyz` for those). Open even with `SPACEARM_API_KEYS` set.",
)
async def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    operation_id="readyz",
    response_model=Health,
    summary="Readiness: the engine's kernels are loaded; the database is reachable, takes writes and is at the head revision",
    description="200 once the engine's compiled kernels are loaded and the database is reachable, writable and migrated "
    "to the revision this version needs (`revision` = `head`); otherwise 503 saying which is not (`kernels`: "
    "`loading` while the kernels compile or load at start-up). Answers within about 3 s however busy the API is. "
    "Open even with `SPACEARM_API_KEYS` set.",
    responses={503: {"description": "not ready (see `kernels` and `database`)", "model": Health, "headers": openapi.RETRY_AFTER}},
)
async def readyz(request: Request) -> Health | JSONResponse:
    state = request.app.state
    kernels = state.kernels.state
    if kernels != "ok":
        return JSONResponse(Health(status="unavailable", kernels=kernels).model_dump(exclude_none=True), status_code=503)
    health: Health | None = None
    with anyio.move_on_after(READY_TIMEOUT_S):
        health = await anyio.to_thread.run_sync(
            check_database, state.health_db, state.db, limiter=state.health_limiter, abandon_on_cancel=True
        )
    if health is None:
        health = Health(status="unavailable", kernels=kernels, database=f"no answer within {READY_TIMEOUT_S:g} s")
    if health.status != "ok":
        return JSONResponse(health.model_dump(exclude_none=True), status_code=503, headers={"Retry-After": "5"})
    return health
