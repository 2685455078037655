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
    summary="Readiness: the database is reachable and at the head revision",
    responses={503: {"description": "not ready", "model": Health}},
)
def readyz(request: Request) -> Health | JSONResponse:
    db: Database = request.app.state.db
    head = head_revision(db.url)
    try:
        revision = current_revision(db.engine)
    except Exception as exc:
        body = Health(status="unavailable", database=f"unreachable: {type(exc).__name__}", head=head)
        return JSONResponse(body.model_dump(), status_code=503)
    if revision != head:
        body = Health(status="unavailable", database="not migrated", revision=revision, head=head)
        return JSONResponse(body.model_dump(), status_code=503)
    return Health(status="ok", database="ok", revision=revision, head=head)
