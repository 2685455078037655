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


def test_a_job_writes_its_progress_once_per_generation(tmp_path: Path) -> None:
    """A worker appends one history row and updates the progress summary in one statement pair,
    one transaction per finished generation (never rewriting the history); the watcher's lease
    renewals carry no progress."""
    from sqlalchemy import event, select

    from service.models import JobGeneration
    from service.schemas.common import PAPER_TASK_EXAMPLE
    from service.usecases.tuning_run import run_job

    db = _db(tmp_path)
    from service.usecases.robots import seed_presets

    seed_presets(db)
    generations = 3
    request = {
        "robot_id": "table1",
        "tasks": [{**PAPER_TASK_EXAMPLE, "dt_s": 0.5}],
        "method": "adaptive",
        "ga": {"population": 6, "generations": generations, "seed": 2},
        "compare_with_dls": True,
    }
    with db.session() as s:
        job = TuningJob(status="queued", request=request, attempts=0, max_attempts=3, cancel_requested=False)
        s.add(job)
        s.flush()
        job_id = job.id
    claim = queue.claim(db, "w", 60)
    assert claim is not None and claim.job_id == job_id
    writes: list[str] = []

    @event.listens_for(db.engine, "before_cursor_execute")
    def _count(conn, cursor, statement, parameters, context, executemany):  # type: ignore[no-untyped-def]
        sql = " ".join(statement.split()).upper()
        if sql.startswith("INSERT INTO TUNING_JOB_GENERATIONS"):
            writes.append("row")
        elif sql.startswith("UPDATE TUNING_JOBS SET") and "PROGRESS" in sql.split(" WHERE ")[0]:
            writes.append("progress")

    assert run_job(db, claim, 60.0, threading.Event()) == "succeeded"
    phases = 2
    per_phase = generations + 1  # the initial population and each generation
    # one row per finished generation and per record of the refinement after each GA, and one
    # summary with each, and the final one with the result
    assert writes.count("progress") == writes.count("row") + 1
    with db.session() as s:
        rows = s.scalars(select(JobGeneration).where(JobGeneration.job_id == job_id).order_by(JobGeneration.seq)).all()
        assert [r.seq for r in rows] == list(range(1, writes.count("row") + 1))
        ga = [r.role for r in rows if r.stage == "ga"]
        assert ga == ["tuned"] * per_phase + ["dls_baseline"] * per_phase
        refined = [(r.role, r.generation) for r in rows if r.stage == "refine"]
        assert {role for role, _ in refined} == {"tuned", "dls_baseline"}
        assert min(g for _, g in refined) == per_phase  # the refinement continues the GA's numbering
        assert len(ga) + len(refined) == len(rows) and phases == 2
        job = s.get(TuningJob, job_id)
        assert job.status == "succeeded" and "history" not in job.progress and job.progress["records"] == len(rows)
        assert job.result["best_params"].keys() == {"lambda_max", "epsilon"}
    db.dispose()
