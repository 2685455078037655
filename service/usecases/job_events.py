"""What a job's event stream reads: the job's state (status, attempts, the small progress summary)
and only the generation rows it has not sent yet; the request is read once, when the stream
opens (its generation count)."""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from sqlalchemy import select

from service.infra.db import Database
from service.models import JobGeneration, TuningJob
from service.queue import TERMINAL

__all__ = ["TERMINAL", "Snapshot", "read_job", "status_summary"]


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
    rows: list[dict[str, Any]] = field(default_factory=list)  # rows of the current attempt after the last one sent

    @property
    def attempt(self) -> int:
        """The attempt whose history the job shows."""
        return int(self.progress.get("attempt", self.attempts))

    @property
    def records(self) -> int:
        """Generation rows of that attempt so far."""
        return int(self.progress.get("records", 0))


def read_job(db: Database, job_id: str, previous: Snapshot | None, after: int) -> Snapshot | None:
    """The job's state, and its generation rows of the current attempt with ``seq > after`` (read
    only when the job changed since ``previous``); None if the job is gone."""
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
        if previous is None:
            request = session.scalar(select(TuningJob.request).where(TuningJob.id == job_id)) or {}
            generations = int((request.get("ga") or {}).get("generations", 50))
            phases = 2 if request.get("compare_with_dls", True) else 1
        else:
            generations, phases = previous.generations, previous.phases
        snap = Snapshot(
            row.status, row.attempts, row.cancel_requested, row.error, row.updated_at, row.progress or {}, generations, phases
        )
        if previous is None or row.updated_at != previous.updated_at:
            rows = session.scalars(
                select(JobGeneration)
                .where(JobGeneration.job_id == job_id, JobGeneration.attempt == snap.attempt, JobGeneration.seq > after)
                .order_by(JobGeneration.seq)
            ).all()
            snap.rows = [
                {k: getattr(r, k) for k in ("seq", "phase", "role", "generation", "best", "mean", "feasible")} for r in rows
            ]
    return snap


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
