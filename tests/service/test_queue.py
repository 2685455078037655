"""The queue on a real SQLite file: concurrent claims never hand one job to two workers; expired
leases go back to the queue until the attempts are used up."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from service import queue
from service.infra.db import Database
from service.infra.migrate import upgrade
from service.models import TuningJob


def _db(tmp_path: Path) -> Database:
    url = f"sqlite:///{tmp_path / 'q.db'}"
    upgrade(url)
    return Database(url)


def add_jobs(db: Database, n: int, max_attempts: int = 3) -> list[str]:
    with db.session() as s:
        jobs = [
            TuningJob(status="queued", request={}, attempts=0, max_attempts=max_attempts, cancel_requested=False)
            for _ in range(n)
        ]
        s.add_all(jobs)
        s.flush()
        return [j.id for j in jobs]


def claim_concurrently(db: Database, threads: int = 8) -> list[str]:
    """Threads claim until the queue is empty; returns every claimed id (duplicates kept)."""
    claimed: list[str] = []
    lock = threading.Lock()

    def worker(name: str) -> None:
        while (c := queue.claim(db, name, 60)) is not None:
            with lock:
                claimed.append(c.job_id)

    pool = [threading.Thread(target=worker, args=(f"w{i}",)) for i in range(threads)]
    for t in pool:
        t.start()
    for t in pool:
        t.join()
    return claimed


def test_concurrent_claims_are_exclusive(tmp_path: Path) -> None:
    db = _db(tmp_path)
    ids = add_jobs(db, 40)
    assert sorted(claim_concurrently(db)) == sorted(ids)  # each exactly once
    db.dispose()


def test_expired_lease_requeues_until_attempts_exhausted(tmp_path: Path) -> None:
    db = _db(tmp_path)
    (job_id,) = add_jobs(db, 1, max_attempts=2)
    first = queue.claim(db, "a", 0.05)
    assert first is not None and first.attempts == 1
    assert queue.claim(db, "b", 0.05) is None  # lease still held
    time.sleep(0.1)
    second = queue.claim(db, "b", 0.05)
    assert second is not None and second.job_id == job_id and second.attempts == 2
    assert queue.heartbeat(db, first, 10) == "lost"  # the dead worker cannot write any more
    assert not queue.finish(db, first, {})
    time.sleep(0.1)
    assert queue.claim(db, "c", 0.05) is None
    with db.session() as s:
        job = s.get(TuningJob, job_id)
        assert job is not None and job.status == "failed" and "attempts" in (job.error or "")
    db.dispose()


def test_cancel_flags_running_job(tmp_path: Path) -> None:
    db = _db(tmp_path)
    (job_id,) = add_jobs(db, 1)
    c = queue.claim(db, "a", 60)
    assert c is not None
    assert queue.heartbeat(db, c, 60, {"generation": 1}) == "ok"
    assert queue.request_cancel(db, job_id) == "running"
    assert queue.heartbeat(db, c, 60) == "cancel"
    assert queue.mark_cancelled(db, c)
    assert queue.request_cancel(db, "missing") is None
    db.dispose()
