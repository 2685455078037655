"""Liveness and readiness."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service.db import Database
from service.migrate import current_revision, head_revision
from service.schemas import Health

router = APIRouter(tags=["health"])


@router.get("/healthz", operation_id="healthz", response_model=Health, response_model_exclude_none=True, summary="Liveness")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    operation_id="readyz",
    response_model=Health,
    summary="Readiness: the engine's kernels are loaded, the database is reachable and at the head revision",
    responses={503: {"description": "not ready", "model": Health}},
)
def readyz(request: Request) -> Health | JSONResponse:
    kernels = request.app.state.kernels.state
    if kernels != "ok":
        return JSONResponse(Health(status="unavailable", kernels=kernels).model_dump(exclude_none=True), status_code=503)
    db: Database = request.app.state.db
    head = head_revision(db.url)
    try:
        revision = current_revision(db.engine)
    except Exception as exc:
        body = Health(status="unavailable", kernels=kernels, database=f"unreachable: {type(exc).__name__}", head=head)
        return JSONResponse(body.model_dump(), status_code=503)
    if revision != head:
        body = Health(status="unavailable", kernels=kernels, database="not migrated", revision=revision, head=head)
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", kernels=kernels, database="ok", revision=revision, head=head)
