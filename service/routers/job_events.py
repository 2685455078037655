"""Live progress of a tuning job as Server-Sent Events (FastAPI's own ``EventSourceResponse``).

The streams of a job read the database through one shared feed per API process
(:mod:`service.usecases.job_events`: one read every :data:`POLL_S` however many listen), so
they work with any number of API processes and workers; a process keeps at most
``SPACEARM_MAX_EVENT_STREAMS`` streams open (503 with ``Retry-After`` beyond). Events:

- ``status`` (no id): a snapshot of the job (status, attempts, progress summary) when the
  stream opens and whenever its status, attempt, cancellation or error changes;
- ``generation`` (id ``<attempt>.<n>``, the n-th record of that attempt): one per finished
  generation of each GA phase, with the phase, its generation count and B, and each round of the
  refinement after it (``stage`` ``refine``, numbered on from the GA's last generation);
- ``end`` (no id): the job's final status; the stream then closes.

A comment line is sent after :attr:`Settings.sse_heartbeat_s` without events, so proxies keep
the connection open. A reconnecting client (``Last-Event-ID`` header, or ``last_event_id``
query parameter for a first connection) gets the generations after that id; an id from an
earlier attempt (the job was retried after its worker died) replays the current attempt.
"""

from __future__ import annotations

import re
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Annotated

from fastapi import APIRouter, Depends, Header, Query, Request
from fastapi.sse import EventSourceResponse, ServerSentEvent

from service.deps import JobId, SessionRoute
from service.errors import ApiValidationError, NotFoundError, responses
from service.usecases.job_events import JobFeed, JobFeeds, events

router = APIRouter(prefix="/v1/tuning-jobs", tags=["tuning"], route_class=SessionRoute)

POLL_S = 0.5  # how often a job's feed reads it
RETRY_MS = 2000  # how long a browser waits before reconnecting
EVENT_ID = re.compile(r"^([0-9]{1,9})\.([0-9]{1,9})$")


@dataclass
class StreamStart:
    feed: JobFeed
    after: tuple[int, int] | None  # (attempt, record) of the last event the client saw


def feeds_of(request: Request) -> JobFeeds:
    feeds: JobFeeds = request.app.state.job_feeds
    return feeds


async def stream_start(
    job_id: JobId,
    request: Request,
    last_event_id_header: Annotated[
        str | None, Header(alias="Last-Event-ID", max_length=40, description="sent by a reconnecting EventSource")
    ] = None,
    last_event_id: Annotated[
        str | None, Query(max_length=40, description="the last event id seen, for a first connection that resumes")
    ] = None,
) -> AsyncIterator[StreamStart]:
    """Join the job's feed (503 when the process has its streams' worth), load the job (404) and
    check the resume point (422) before the stream starts; leave the feed when the stream ends."""
    async with feeds_of(request).listen(job_id) as feed:
        if feed.snapshot is None:
            raise NotFoundError("tuning job", job_id)
        given, loc = (last_event_id_header, ["header", "Last-Event-ID"])
        if given is None:
            given, loc = (last_event_id, ["query", "last_event_id"])
        if given is None:
            yield StreamStart(feed, None)
            return
        match = EVENT_ID.match(given.strip())
        point = (int(match[1]), int(match[2])) if match is not None else None
        if point is not None and point > (feed.snapshot.attempt, feed.snapshot.records):
            await feed.refresh()  # another process may have sent it: read the job now
        snap = feed.snapshot
        if snap is None:
            raise NotFoundError("tuning job", job_id)
        attempt, records = snap.attempt, snap.records
        if point is None or point > (attempt, records):
            sent = f"its ids run from {attempt}.1 to {attempt}.{records}" if records else "it has sent no generation yet"
            msg = f"unknown event id {given!r} (ids are <attempt>.<record>): {sent}"
            raise ApiValidationError.at(loc, msg)
        yield StreamStart(feed, point)


@router.get(
    "/{job_id:id}/events",
    operation_id="get_tuning_job_events",
    response_class=EventSourceResponse,
    summary="Live progress of a tuning job (Server-Sent Events)",
    description="A `text/event-stream`: `status` events (a snapshot when the stream opens and at every change of "
    "status), one `generation` event per finished GA generation or refinement round (id `<attempt>.<record>`, "
    "data: phase, role, stage `ga` or `refine`, generation, generations, best and mean B, feasible count), then "
    "`end` with the final status, and the stream closes. Heartbeat comments keep idle connections open. Resume "
    "with `Last-Event-ID` (an EventSource sends it when it reconnects) or `?last_event_id=`; an id this job never "
    "sent is a 422. Each API process keeps at most `SPACEARM_MAX_EVENT_STREAMS` streams open: beyond, a 503 with "
    "`Retry-After`.",
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
    heartbeat_s: float = request.app.state.settings.sse_heartbeat_s
    async for event in events(start.feed, start.after, heartbeat_s):
        if event.kind == "heartbeat":
            yield ServerSentEvent(comment="heartbeat")
        else:
            retry = RETRY_MS if event.kind == "status" else None
            yield ServerSentEvent(event=event.kind, id=event.id, data=event.data, retry=retry)
