"""The same service on PostgreSQL (a throwaway cluster, see ``conftest_pg.py``): migrations, the
API with two workers, exclusive concurrent claims, and a worker killed mid-job. Each test gets a
fresh database on the session's cluster."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from sqlalchemy import inspect

from service import queue
from service.infra.db import Database, make_engine
from service.infra.migrate import current_revision, downgrade, head_revision, upgrade
from service.models import TuningJob
from tests.service.conftest import PAPER_TASK, Stack, wait_for
from tests.service.conftest_pg import Cluster, create_database, own_cluster, pg_url, postgres_url  # noqa: F401  (fixtures)
from tests.service.test_jobs import two_workers_share_the_queue, worker_killed_mid_job_another_finishes
from tests.service.test_migrations import TABLES
from tests.service.test_queue import add_jobs, claim_concurrently
from tests.service.test_reliability import worker_outlives_an_outage


def test_pg_upgrade_downgrade_roundtrip(pg_url: str) -> None:  # noqa: F811
    assert pg_url.startswith("postgresql+psycopg://")
    upgrade(pg_url)
    engine = make_engine(pg_url)
    try:
        assert engine.dialect.name == "postgresql"
        assert set(inspect(engine).get_table_names()) >= TABLES
        assert current_revision(engine) == head_revision(pg_url) == "0007"
        downgrade(pg_url)
        assert not TABLES & set(inspect(engine).get_table_names())
        assert current_revision(engine) is None
        upgrade(pg_url)
        assert set(inspect(engine).get_table_names()) >= TABLES
        assert current_revision(engine) == "0007"
    finally:
        engine.dispose()


def test_pg_api_and_two_workers(make_stack: Callable[..., Stack], pg_url: str) -> None:  # noqa: F811
    stack = make_stack(database_url=pg_url)
    stack.start_api()
    with stack.client() as client:
        ready = client.get("/readyz")
        assert ready.status_code == 200 and ready.json()["revision"] == "0007", ready.text
        r = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "replay": False})
        assert r.status_code == 201, r.text
        plan = r.json()
        stored = client.get(f"/v1/plans/{plan['id']}").json()
        assert stored["metrics"] == plan["metrics"] and stored["success"] is plan["success"]
        assert plan["id"] in [p["id"] for p in client.get("/v1/plans").json()["items"]]
        # the list's filters read the stored JSON (->> on PostgreSQL, json_extract on SQLite)
        kept = {"robot_id": "table1", "path_type": "line", "method": "adaptive", "success": str(plan["success"]).lower()}
        assert [p["id"] for p in client.get("/v1/plans", params=kept).json()["items"]] == [plan["id"]]
        for other in ({"path_type": "raster"}, {"method": "dls"}, {"success": str(not plan["success"]).lower()}):
            assert client.get("/v1/plans", params={**kept, **other}).json()["total"] == 0, other
        # PostgreSQL cannot store NUL characters (SQLite can): a 422, not a 500
        robot = client.get("/v1/robots/table1").json()["parameters"]
        nul = client.post("/v1/robots", json={**robot, "name": "a\x00b"})
        assert nul.status_code == 422 and nul.json()["errors"][0]["field"] == "body.name", nul.text
        assert client.get("/v1/robots/a%00b").status_code == 422
        headers = {"Idempotency-Key": "pg-1"}
        first = client.post("/v1/tuning-jobs", json={**PAPER_JOB}, headers=headers).json()
        assert client.post("/v1/tuning-jobs", json={**PAPER_JOB}, headers=headers).json()["id"] == first["id"]
        assert client.post(f"/v1/tuning-jobs/{first['id']}/cancel").json()["status"] == "cancelled"
    ids = two_workers_share_the_queue(stack, jobs=6)
    with stack.client() as client:
        listing = client.get("/v1/tuning-jobs", params={"status": "succeeded"}).json()
        assert sorted(j["id"] for j in listing["items"]) == sorted(ids)
        result = client.get(f"/v1/tuning-jobs/{ids[0]}/result").json()
        assert set(result["best_params"]) == {"lambda_max", "epsilon"}


PAPER_JOB = {
    "robot_id": "table1",
    "tasks": [PAPER_TASK],
    "method": "adaptive",
    "ga": {"population": 4, "generations": 1, "seed": 1},
    "compare_with_dls": False,
}


def test_pg_concurrent_claims_are_exclusive(pg_url: str) -> None:  # noqa: F811
    upgrade(pg_url)
    db = Database(pg_url)
    try:
        ids = add_jobs(db, 60)
        claimed = claim_concurrently(db, threads=8)
        assert len(claimed) == len(set(claimed))  # no job claimed twice
        assert sorted(claimed) == sorted(ids)  # and none left behind (SKIP LOCKED, not a lost race)
        with db.session() as s:
            assert all(j.status == "running" and j.attempts == 1 for j in s.query(TuningJob))
        # simultaneous claims with jobs to spare: every worker gets one (losing a race on the
        # same row must not make a worker think the queue is empty)
        ids = add_jobs(db, 40)
        for _ in range(5):
            barrier = threading.Barrier(8)
            got: list[queue.Claim | None] = []

            def one(name: str, got: list[queue.Claim | None] = got, barrier: threading.Barrier = barrier) -> None:
                barrier.wait()
                got.append(queue.claim(db, name, 60))

            threads = [threading.Thread(target=one, args=(f"r{i}",)) for i in range(8)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert None not in got, got
            assert len({c.job_id for c in got if c}) == 8
    finally:
        db.dispose()


def test_pg_expired_lease_and_timezones(pg_url: str) -> None:  # noqa: F811
    upgrade(pg_url)
    db = Database(pg_url)
    try:
        (job_id,) = add_jobs(db, 1, max_attempts=2)
        first = queue.claim(db, "a", 0.2)
        assert first is not None and queue.claim(db, "b", 0.2) is None  # lease held
        with db.session() as s:
            job = s.get(TuningJob, job_id)
            assert job is not None and job.lease_expires_at is not None and job.lease_expires_at.utcoffset() is not None
        time.sleep(0.3)
        second = wait_for(lambda: queue.claim(db, "b", 60), timeout=5)
        assert second.job_id == job_id and second.attempts == 2
        assert queue.heartbeat(db, first, 10) == "lost" and queue.heartbeat(db, second, 60) == "ok"
        assert queue.request_cancel(db, job_id) == "running" and queue.heartbeat(db, second, 60) == "cancel"
    finally:
        db.dispose()


def test_pg_worker_killed_mid_job_another_finishes(make_stack: Callable[..., Stack], pg_url: str) -> None:  # noqa: F811
    worker_killed_mid_job_another_finishes(make_stack(lease_seconds=1.0, database_url=pg_url))


def test_pg_server_stopped_and_started_again_under_the_api_and_a_worker(
    make_stack: Callable[..., Stack],
    own_cluster: Cluster,  # noqa: F811
) -> None:
    """``pg_ctl stop -m fast`` (sessions ended, connections refused) under a running API and worker,
    idle and mid-job: 503s, a worker that waits and gives its job back, no process exits."""
    stack = make_stack(lease_seconds=3.0, database_url=create_database(own_cluster.admin_url))
    worker_outlives_an_outage(stack, own_cluster.stop, own_cluster.start, "cannot be reached")
