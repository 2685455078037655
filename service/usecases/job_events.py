"""What a job's event streams read, shared by every stream of the job in this API process.

A :class:`JobFeed` polls one job for all its listeners: one read every ``poll_s`` while anyone
listens, whatever their number, of the job's state (status, attempts, the small progress
summary) and of only the generation rows it has not read yet (read only when the job changed).
Its generation count comes from two values inside the stored request, extracted by the
database, so the request (up to a megabyte) is never read or decoded. :class:`JobFeeds` holds
the feeds of the process and caps the streams open at once (a 503 with ``Retry-After`` beyond).

:func:`events` turns a feed into one listener's events (``status``, ``generation`` with id
``<attempt>.<seq>``, ``end``, heartbeats), from its resume point on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select

from service.infra.admission import OverloadedError
from service.infra.db import Database
from service.infra.metrics import EVENT_STREAM_POLLS, EVENT_STREAMS_OPEN, EVENT_STREAMS_REFUSED
from service.models import JobGeneration, TuningJob
from service.queue import TERMINAL

__all__ = ["TERMINAL", "Event", "JobFeed", "JobFeeds", "Snapshot", "events", "status_summary"]

log = logging.getLogger("spacearm.api")
ROW_FIELDS = ("seq", "phase", "role", "stage", "generation", "best", "mean", "feasible")
RETRY_AFTER_S = 5  # of a 503 when every stream of the process is taken


@dataclass
class Snapshot:
    status: str
    attempts: int
    cancel_requested: bool
    error: str | None
    updated_at: datetime | None
    progress: dict[str, Any]
    generations: int  # of one GA phase
    phases: int

    @property
    def attempt(self) -> int:
        """The attempt whose history the job shows."""
        return int(self.progress.get("attempt", self.attempts))

    @property
    def records(self) -> int:
        """Generation rows of that attempt so far."""
        return int(self.progress.get("records", 0))


def _shape(db: Database, job_id: str) -> tuple[int, int] | None:
    """``(generations of one phase, phases)`` from the stored request, extracted by the database
    (as :meth:`service.schemas.tuning.TuningJobRequest.phases` counts them)."""
    request = TuningJob.request
    with db.session() as session:
        row = session.execute(
            select(
                request["ga"]["generations"].as_integer(),
                request["compare_with_dls"].as_boolean(),
                request["compare_with_bounded"].as_boolean(),
                request["method"].as_string(),
            ).where(TuningJob.id == job_id)
        ).first()
    if row is None:
        return None
    generations, dls, bounded, method = row
    phases = 1 + (dls is not False) + (bounded is True and method != "bounded")
    return (50 if generations is None else int(generations)), phases


def _read(
    db: Database, job_id: str, shape: tuple[int, int], previous: Snapshot | None, after: int
) -> tuple[Snapshot, list[dict[str, Any]]] | None:
    """The job's state, and its generation rows of the current attempt with ``seq > after``
    (read only when the job changed since ``previous``); None if the job is gone."""
    columns = (
        TuningJob.status,
        TuningJob.attempts,
        TuningJob.cancel_requested,
        TuningJob.error,
        TuningJob.updated_at,
        TuningJob.progress,
    )
    with db.session() as session:
        row = session.execute(select(*columns).where(TuningJob.id == job_id)).first()
        if row is None:
            return None
        snap = Snapshot(row.status, row.attempts, row.cancel_requested, row.error, row.updated_at, row.progress or {}, *shape)
        if previous is not None and row.updated_at == previous.updated_at:
            return snap, []
        if previous is not None and previous.attempt != snap.attempt:
            after = 0
        rows = session.scalars(
            select(JobGeneration)
            .where(JobGeneration.job_id == job_id, JobGeneration.attempt == snap.attempt, JobGeneration.seq > after)
            .order_by(JobGeneration.seq)
        ).all()
        return snap, [{k: getattr(r, k) for k in ROW_FIELDS} for r in rows]


class JobFeed:
    """One job as this process's listeners share it: :attr:`snapshot` (None once the job is
    gone), :attr:`rows` (the generation rows of the snapshot's attempt so far, in order) and a
    version that grows at every change (:meth:`wait`)."""

    def __init__(self, db: Database, job_id: str, poll_s: float) -> None:
        self.db = db
        self.job_id = job_id
        self.poll_s = poll_s
        self.snapshot: Snapshot | None = None
        self.rows: list[dict[str, Any]] = []
        self.version = 0
        self.listeners = 0
        self._shape: tuple[int, int] | None = None
        self._changed = asyncio.Event()
        self._ready = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self._error: BaseException | None = None
        self._reading = asyncio.Lock()  # one read at a time: the loop's, or a listener's refresh
        self._failing = False

    @property
    def done(self) -> bool:
        """Nothing more will change: the job ended or is gone."""
        return self._ready.is_set() and (self.snapshot is None or self.snapshot.status in TERMINAL)

    def start(self) -> None:
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name=f"job-feed-{self.job_id}")

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()

    async def ready(self) -> None:
        """Wait for the first read; raise what it raised (a database fault, for a 503)."""
        await self._ready.wait()
        if self._error is not None:
            raise self._error

    async def refresh(self) -> None:
        """One read now (a listener that resumes from an id newer than the feed's state)."""
        await self._poll()

    async def wait(self, version: int, timeout_s: float) -> int:
        """Wait until the version is past ``version`` (or ``timeout_s``); the version then."""
        if self.version == version:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), timeout_s)
        return self.version

    async def _run(self) -> None:
        try:
            while True:
                try:
                    await self._poll()
                except Exception as exc:  # a database fault: the first read reports it; later ones are retried
                    if not self._ready.is_set():
                        self._error = exc
                        self._ready.set()
                        return
                    if not self._failing:  # once per fault, not every poll
                        log.warning("event streams of job %s: reading it failed (%s); retrying", self.job_id, type(exc).__name__)
                    self._failing = True
                else:
                    self._failing = False
                if self.done:
                    return
                await asyncio.sleep(self.poll_s)
        finally:
            self._ready.set()

    async def _poll(self) -> None:
        async with self._reading:
            await self._read_once()

    async def _read_once(self) -> None:
        EVENT_STREAM_POLLS.inc()
        if self._shape is None:
            self._shape = await run_in_threadpool(_shape, self.db, self.job_id)
            if self._shape is None:
                self._publish(None, [])
                return
        after = self.rows[-1]["seq"] if self.rows else 0
        read = await run_in_threadpool(_read, self.db, self.job_id, self._shape, self.snapshot, after)
        if read is None:
            self._publish(None, [])
            return
        snap, rows = read
        if self.snapshot is not None and snap.attempt != self.snapshot.attempt:
            self.rows = []  # a retry starts its history anew
        self._publish(snap, rows)

    def _publish(self, snap: Snapshot | None, rows: list[dict[str, Any]]) -> None:
        changed = snap != self.snapshot or rows
        self.snapshot = snap
        self.rows.extend(rows)
        self._ready.set()
        if changed:
            self.version += 1
            self._changed.set()
            self._changed = asyncio.Event()


class JobFeeds:
    """The feeds of this process, and the cap on its open streams (``max_streams``)."""

    def __init__(self, db: Database, poll_s: float, max_streams: int) -> None:
        self.db = db
        self.poll_s = poll_s
        self.max_streams = max_streams
        self.open = 0
        self.feeds: dict[str, JobFeed] = {}

    @contextlib.asynccontextmanager
    async def listen(self, job_id: str) -> AsyncIterator[JobFeed]:
        """The job's feed, its first read done, for one stream; 503 when the process has
        ``max_streams`` streams open."""
        if self.open >= self.max_streams:
            EVENT_STREAMS_REFUSED.inc()
            raise OverloadedError(f"event streams (at most {self.max_streams} per API process)", RETRY_AFTER_S)
        feed = self.feeds.get(job_id)
        if feed is None:
            feed = self.feeds[job_id] = JobFeed(self.db, job_id, self.poll_s)
        self.open += 1
        feed.listeners += 1
        EVENT_STREAMS_OPEN.inc()
        try:
            feed.start()
            await feed.ready()
            yield feed
        finally:
            self.open -= 1
            feed.listeners -= 1
            EVENT_STREAMS_OPEN.dec()
            if feed.listeners == 0 and self.feeds.get(job_id) is feed:
                del self.feeds[job_id]
                feed.stop()


@dataclass
class Event:
    """One event of a stream: ``kind`` is ``status``, ``generation``, ``end`` or ``heartbeat``."""

    kind: str
    data: dict[str, Any] = field(default_factory=dict)
    id: str | None = None


def _status_state(snap: Snapshot) -> tuple[Any, ...]:
    """What a ``status`` event is sent again for when it changes."""
    return (snap.status, snap.attempts, snap.cancel_requested, snap.error)


def status_summary(snap: Snapshot) -> dict[str, Any]:
    """The data of a ``status`` event."""
    progress = snap.progress
    return {
        "status": snap.status,
        "attempts": snap.attempts,
        "cancel_requested": snap.cancel_requested,
        "error": snap.error,
        "phase": progress.get("phase"),
        "generation": int(progress.get("generation", 0)),
        "generations": snap.generations * snap.phases,
        "evaluations": progress.get("evaluations", 0),
        "best_objective_b": progress.get("best_objective_b"),
        "best_params": progress.get("best_params"),
    }


async def events(feed: JobFeed, after: tuple[int, int] | None, heartbeat_s: float) -> AsyncIterator[Event]:
    """One listener's events from ``feed``: the generations after ``after`` (``(attempt, seq)``
    of the last event the client saw; an earlier attempt's id replays the current attempt), a
    ``status`` at the start and at every change of status, ``end`` when the job ends (or is
    deleted), and a heartbeat after ``heartbeat_s`` without events."""
    snap = feed.snapshot
    attempt = snap.attempt if snap is not None else 0
    sent = after[1] if after is not None and after[0] == attempt else 0
    shown: tuple[Any, ...] | None = None
    if snap is not None:  # the job as it is, before the generations already run (the backlog)
        shown = _status_state(snap)
        yield Event("status", {"id": feed.job_id, **status_summary(snap)})
    quiet_since = time.monotonic()
    while True:
        version = feed.version  # before reading: a change while this listener waits to send is not missed
        snap = feed.snapshot
        if snap is None:  # deleted while streaming
            yield Event("end", {"id": feed.job_id, "status": "deleted"})
            return
        if snap.attempt != attempt:  # a retry starts its history anew
            attempt, sent = snap.attempt, 0
        for row in feed.rows:
            if row["seq"] > sent:
                data = {k: row[k] for k in ROW_FIELDS if k != "seq"}
                yield Event("generation", {**data, "generations": snap.generations}, f"{attempt}.{row['seq']}")
                sent = row["seq"]
                quiet_since = time.monotonic()
        state = _status_state(snap)
        if state != shown:
            shown = state
            yield Event("status", {"id": feed.job_id, **status_summary(snap)})
            quiet_since = time.monotonic()
        if snap.status in TERMINAL:
            yield Event("end", {"id": feed.job_id, "status": snap.status})
            return
        if time.monotonic() - quiet_since >= heartbeat_s:
            yield Event("heartbeat")
            quiet_since = time.monotonic()
        await feed.wait(version, max(0.01, heartbeat_s - (time.monotonic() - quiet_since)))
