"""Live progress of a tuning job as Server-Sent Events (FastAPI's own ``EventSourceResponse``).

The stream reads the database (every :data:`POLL_S`), so it works with any number of API
processes and workers. Events:

- ``status`` (no id): a snapshot of the job (status, attempts, progress summary) when the
  stream opens and whenever its status, attempt, cancellation or error changes;
- ``generation`` (id ``<attempt>.<n>``, the n-th record of that attempt): one per finished
  generation of each GA phase, with the phase, its generation count and B;
- ``end`` (no id): the job's final status; the stream then closes.

A comment line is sent after :attr:`Settings.sse_heartbeat_s` without events, so proxies keep
the connection open. A reconnecting client (``Last-Event-ID`` header, or ``last_event_id``
query parameter for a first connection) gets the generations after that id; an id from an
earlier attempt (the job was retried after its worker died) replays the current attempt.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.sse import EventSourceResponse, ServerSentEvent

from service.deps import JobId, SessionRoute
from service.errors import ApiValidationError, NotFoundError, responses
from service.usecases.job_events import TERMINAL, Snapshot, read_job, status_summary

router = APIRouter(prefix="/v1/tuning-jobs", tags=["tuning"], route_class=SessionRoute)

POLL_S = 0.5  # how often an open stream reads the job
RETRY_MS = 2000  # how long a browser waits before reconnecting
EVENT_ID = re.compile(r"^([0-9]{1,9})\.([0-9]{1,9})$")


@dataclass
class StreamStart:
    job_id: str
    snapshot: Snapshot
    after: tuple[int, int] | None  # (attempt, record) of the last event the client saw


async def stream_start(
    job_id: JobId,
    request: Request,
    last_event_id_header: Annotated[
        str | None, Header(alias="Last-Event-ID", max_length=40, description="sent by a reconnecting EventSource")
    ] = None,
    last_event_id: Annotated[
        str | None, Query(max_length=40, description="the last event id seen, for a first connection that resumes")
    ] = None,
) -> StreamStart:
    """Load the job (404) and check the resume point (422) before the stream starts."""
    snapshot = await run_in_threadpool(read_job, request.app.state.db, job_id, None, 0)
    if snapshot is None:
        raise NotFoundError("tuning job", job_id)
    given, loc = (last_event_id_header, ["header", "Last-Event-ID"])
    if given is None:
        given, loc = (last_event_id, ["query", "last_event_id"])
    if given is None:
        return StreamStart(job_id, snapshot, None)
    match = EVENT_ID.match(given.strip())
    attempt, records = snapshot.attempt, snapshot.records
    if match is None or (int(match[1]), int(match[2])) > (attempt, records):
        sent = f"its ids run from {attempt}.1 to {attempt}.{records}" if records else "it has sent no generation yet"
        msg = f"unknown event id {given!r} (ids are <attempt>.<record>): {sent}"
        raise ApiValidationError(f"{'.'.join(loc)}: {msg}", [{"loc": loc, "msg": msg}])
    return StreamStart(job_id, snapshot, (int(match[1]), int(match[2])))


def status_event(job_id: str, snap: Snapshot) -> ServerSentEvent:
    return ServerSentEvent(event="status", data={"id": job_id, **status_summary(snap)}, retry=RETRY_MS)


def generation_event(snap: Snapshot, attempt: int, row: dict[str, Any]) -> ServerSentEvent:
    data = {k: row[k] for k in ("phase", "role", "generation", "best", "mean", "feasible")}
    return ServerSentEvent(event="generation", id=f"{attempt}.{row['seq']}", data={**data, "generations": snap.generations})


@router.get(
    "/{job_id:id}/events",
    operation_id="get_tuning_job_events",
    response_class=EventSourceResponse,
    summary="Live progress of a tuning job (Server-Sent Events)",
    description="A `text/event-stream`: `status` events (a snapshot when the stream opens and at every change of "
    "status), one `generation` event per finished GA generation (id `<attempt>.<record>`, data: phase, role, "
    "generation, generations, best and mean B, feasible count), then `end` with the final status, and the stream "
    "closes. Heartbeat comments keep idle connections open. Resume with `Last-Event-ID` (an EventSource sends it "
    "when it reconnects) or `?last_event_id=`; an id this job never sent is a 422.",
    # `schema`, besides the `itemSchema` (one event) FastAPI documents: the whole body as text, which
    # generators that know no event streams (openapi-python-client) type as a string.
    responses={
        200: {"content": {"text/event-stream": {"schema": {"type": "string", "description": "the event stream, as text"}}}},
        **responses(404, 422),
    },
)
async def get_tuning_job_events(
    start: Annotated[StreamStart, Depends(stream_start)], request: Request
) -> AsyncIterator[ServerSentEvent]:
    db = request.app.state.db
    heartbeat_s: float = request.app.state.settings.sse_heartbeat_s
    snap = start.snapshot
    attempt = snap.attempt
    sent = start.after[1] if start.after is not None and start.after[0] == attempt else 0
    if sent:  # the rows up to the resume point were read with the first snapshot: skip them
        snap.rows = [row for row in snap.rows if row["seq"] > sent]
    shown: tuple[Any, ...] | None = None
    quiet_since = time.monotonic()
    while True:
        if snap.attempt != attempt:  # a retry starts its history anew
            attempt, sent = snap.attempt, 0
        for row in snap.rows:
            if row["seq"] > sent:
                yield generation_event(snap, attempt, row)
                sent = row["seq"]
                quiet_since = time.monotonic()
        state = (snap.status, snap.attempts, snap.cancel_requested, snap.error)
        if state != shown:
            shown = state
            yield status_event(start.job_id, snap)
            quiet_since = time.monotonic()
        if snap.status in TERMINAL:
            yield ServerSentEvent(event="end", data={"id": start.job_id, "status": snap.status})
            return
        if time.monotonic() - quiet_since >= heartbeat_s:
            yield ServerSentEvent(comment="heartbeat")
            quiet_since = time.monotonic()
        await asyncio.sleep(POLL_S)
        latest = await run_in_threadpool(read_job, db, start.job_id, snap, sent)
        if latest is None:  # deleted while streaming
            yield ServerSentEvent(event="end", data={"id": start.job_id, "status": "deleted"})
            return
        snap = latest
