"""Retention: finished tuning jobs, plans and landscapes older than ``SPACEARM_RETENTION_DAYS`` are deleted
by a sweeper thread of the API (every ``SPACEARM_RETENTION_SWEEP_S``). Deletes are idempotent,
so several API processes may sweep the same database."""

from __future__ import annotations

import logging
import threading
from datetime import datetime, timedelta

from sqlalchemy import delete

from service.infra.db import Database, is_database_fault, retry_locked
from service.models import Landscape, Plan, TuningJob, utcnow
from service.queue import TERMINAL

log = logging.getLogger("spacearm.retention")


@retry_locked
def purge(db: Database, older_than: datetime) -> tuple[int, int]:
    """Delete plans and landscapes created and tuning jobs finished before ``older_than``;
    returns how many plans (landscapes included) and jobs went. Queued and running jobs are
    never deleted."""
    with db.session() as session:
        plans = session.execute(delete(Plan).where(Plan.created_at < older_than)).rowcount  # type: ignore[attr-defined]
        plans += session.execute(delete(Landscape).where(Landscape.created_at < older_than)).rowcount  # type: ignore[attr-defined]
        jobs = session.execute(  # type: ignore[attr-defined]
            delete(TuningJob).where(TuningJob.status.in_(TERMINAL), TuningJob.finished_at < older_than)
        ).rowcount
    return int(plans or 0), int(jobs or 0)


class Sweeper(threading.Thread):
    """Purges every ``interval_s`` what is older than ``days``, until :meth:`stop`."""

    def __init__(self, db: Database, days: float, interval_s: float) -> None:
        super().__init__(name="retention", daemon=True)
        self.db, self.days, self.interval_s = db, days, interval_s
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.is_set():
            try:
                plans, jobs = purge(self.db, utcnow() - timedelta(days=self.days))
                if plans or jobs:
                    log.info("retention: deleted %d plan(s) and %d finished job(s) older than %g days", plans, jobs, self.days)
            except Exception as exc:  # a database fault: try again next time
                if not is_database_fault(exc):
                    log.exception("retention sweep failed")
                else:
                    log.warning("retention sweep skipped: %s", type(exc).__name__)
            self._stop_event.wait(self.interval_s)

    def stop(self) -> None:
        self._stop_event.set()
        self.join(timeout=5)
