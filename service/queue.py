"""The job queue: the ``tuning_jobs`` table.

- ``claim``: one statement ``UPDATE ... WHERE id = (SELECT ... LIMIT 1 FOR UPDATE SKIP LOCKED)
  AND <claimable> RETURNING``; the condition is repeated on the outer UPDATE, so if two workers
  pick the same id only one update matches (SQLite serialises writers; on PostgreSQL the
  subquery skips rows other workers have locked, so concurrent workers take different jobs). A
  job is claimable when it is queued, or running with an expired lease (its worker died) and
  attempts left.
- ``heartbeat``: renews the lease and writes progress (its summary, and a finished generation
  appended to ``tuning_job_generations``, in one transaction), only while this worker still owns
  the job; it returns whether cancellation was requested or the lease was lost.
- ``finish``/``fail``/``cancelled``/``requeue``: final transitions, again only by the owner.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import and_, or_, select, update

from service.infra.db import Database, retry_locked
from service.models import JobGeneration, TuningJob, utcnow

TERMINAL = ("succeeded", "failed", "cancelled")


@dataclass(frozen=True)
class Claim:
    job_id: str
    worker_id: str
    attempts: int


def _rowcount(result: Any) -> int:
    return int(getattr(result, "rowcount", 0) or 0)


def _claimable(now: datetime) -> Any:
    return and_(
        TuningJob.cancel_requested.is_(False),
        TuningJob.attempts < TuningJob.max_attempts,
        or_(TuningJob.status == "queued", and_(TuningJob.status == "running", TuningJob.lease_expires_at < now)),
    )


@retry_locked
def expire_exhausted(db: Database) -> int:
    """Fail jobs whose lease expired after their last allowed attempt, and finish cancelled ones
    whose worker died."""
    now = utcnow()
    expired = and_(TuningJob.status == "running", TuningJob.lease_expires_at < now)
    with db.session() as s:
        n = _rowcount(
            s.execute(
                update(TuningJob)
                .where(expired, TuningJob.cancel_requested.is_(False), TuningJob.attempts >= TuningJob.max_attempts)
                .values(
                    status="failed",
                    error="the job's worker stopped responding on every attempt (attempts exhausted)",
                    finished_at=now,
                    lease_owner=None,
                    lease_expires_at=None,
                )
                .execution_options(synchronize_session=False)
            )
        )
        n += _rowcount(
            s.execute(
                update(TuningJob)
                .where(expired, TuningJob.cancel_requested.is_(True))
                .values(status="cancelled", finished_at=now, lease_owner=None, lease_expires_at=None)
                .execution_options(synchronize_session=False)
            )
        )
    return int(n)


@retry_locked
def claim(db: Database, worker_id: str, lease_seconds: float) -> Claim | None:
    """Claim the oldest claimable job for ``worker_id``; None if there is none."""
    expire_exhausted(db)
    now = utcnow()
    # FOR UPDATE SKIP LOCKED (PostgreSQL; SQLite has no row locks and leaves it out): a worker
    # skips a row another worker is claiming right now and takes the next one, instead of
    # waiting for it and then finding it taken (which would look like an empty queue).
    candidate = (
        select(TuningJob.id)
        .where(_claimable(now))
        .order_by(TuningJob.created_at, TuningJob.id)
        .limit(1)
        .with_for_update(skip_locked=True)
        .scalar_subquery()
    )
    stmt = (
        update(TuningJob)
        .where(TuningJob.id == candidate, _claimable(now))
        .values(
            status="running",
            lease_owner=worker_id,
            worker_id=worker_id,
            lease_expires_at=now + timedelta(seconds=lease_seconds),
            attempts=TuningJob.attempts + 1,
            started_at=now,
            error=None,
        )
        .returning(TuningJob.id, TuningJob.attempts)
        .execution_options(synchronize_session=False)
    )
    with db.session() as s:
        row = s.execute(stmt).first()
    if row is None:
        return None
    return Claim(row[0], worker_id, row[1])


def _owned(claim: Claim) -> Any:
    return and_(TuningJob.id == claim.job_id, TuningJob.lease_owner == claim.worker_id, TuningJob.status == "running")


@retry_locked
def heartbeat(
    db: Database,
    claim: Claim,
    lease_seconds: float,
    progress: dict[str, Any] | None = None,
    generation: dict[str, Any] | None = None,
) -> str:
    """Renew the lease (and store ``progress``, and append ``generation``: the fields of a
    :class:`JobGeneration` but the job and attempt), in one transaction. Returns ``"ok"``,
    ``"cancel"`` (cancellation requested) or ``"lost"`` (another worker owns the job now, or it is
    gone)."""
    values: dict[str, Any] = {"lease_expires_at": utcnow() + timedelta(seconds=lease_seconds)}
    if progress is not None:
        values["progress"] = progress
    with db.session() as s:
        row = s.execute(
            update(TuningJob)
            .where(_owned(claim))
            .values(**values)
            .returning(TuningJob.cancel_requested)
            .execution_options(synchronize_session=False)
        ).first()
        if row is not None and generation is not None:
            s.add(JobGeneration(job_id=claim.job_id, attempt=claim.attempts, **generation))
    if row is None:
        return "lost"
    return "cancel" if row[0] else "ok"


@retry_locked
def _final(db: Database, claim: Claim, **values: Any) -> bool:
    with db.session() as s:
        n = _rowcount(
            s.execute(
                update(TuningJob)
                .where(_owned(claim))
                .values(lease_owner=None, lease_expires_at=None, **values)
                .execution_options(synchronize_session=False)
            )
        )
    return bool(n)


def finish(db: Database, claim: Claim, result: dict[str, Any], progress: dict[str, Any] | None = None) -> bool:
    values: dict[str, Any] = {"status": "succeeded", "result": result, "finished_at": utcnow()}
    if progress is not None:
        values["progress"] = progress
    return _final(db, claim, **values)


def fail(db: Database, claim: Claim, error: str) -> bool:
    return _final(db, claim, status="failed", error=error, finished_at=utcnow())


def mark_cancelled(db: Database, claim: Claim, result: dict[str, Any] | None = None) -> bool:
    """Cancelled as asked, with the best result found so far (None if no generation finished)."""
    return _final(db, claim, status="cancelled", result=result, finished_at=utcnow())


def requeue(db: Database, claim: Claim) -> bool:
    """Give the job back (graceful worker shutdown); the attempt does not count."""
    return _final(db, claim, status="queued", attempts=TuningJob.attempts - 1)


@retry_locked
def request_cancel(db: Database, job_id: str) -> str | None:
    """Cancel a queued job at once, ask a running one to stop. Returns the status afterwards,
    or None if the job does not exist."""
    now = utcnow()
    with db.session() as s:
        s.execute(
            update(TuningJob)
            .where(TuningJob.id == job_id, TuningJob.status == "queued")
            .values(status="cancelled", cancel_requested=True, finished_at=now)
            .execution_options(synchronize_session=False)
        )
        s.execute(
            update(TuningJob)
            .where(TuningJob.id == job_id, TuningJob.status == "running")
            .values(cancel_requested=True)
            .execution_options(synchronize_session=False)
        )
        status = s.scalar(select(TuningJob.status).where(TuningJob.id == job_id))
    return status
