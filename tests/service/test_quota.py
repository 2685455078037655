"""The storage quota (:mod:`service.infra.quota`) on a SQLite file: refused once the pages in use
would exceed it, deleted data freeing room again, and the pages counted only when the files come
near the quota."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from sqlalchemy import create_engine, event, text
from sqlalchemy.orm import Session

from service.infra.db import Database
from service.infra.quota import QuotaExceededError, check_quota, database_bytes, files_bytes
from tests.service.conftest import PAPER_TASK, Stack

BLOB = 256 * 1024


def test_the_quota_counts_pages_in_use_only_near_the_quota(tmp_path: Path) -> None:
    engine = create_engine(f"sqlite:///{tmp_path / 'q.db'}")
    statements: list[str] = []
    event.listen(engine, "before_cursor_execute", lambda *args: statements.append(args[2]))
    with Session(engine) as session:
        session.execute(text("PRAGMA journal_mode=WAL"))
        session.execute(text("CREATE TABLE blobs (id INTEGER PRIMARY KEY, data BLOB)"))
        for i in range(8):
            session.execute(text("INSERT INTO blobs (data) VALUES (:d)"), {"d": bytes([i]) * BLOB})
        session.commit()
        used = database_bytes(session)
        assert 8 * BLOB <= used <= files_bytes(session)
        statements.clear()
        check_quota(session, None, 10**12)
        check_quota(session, 100 * BLOB, BLOB)  # far from it: the files' sizes tell
        assert statements == []
        with pytest.raises(QuotaExceededError) as refused:
            check_quota(session, used + BLOB // 2, BLOB)
        assert refused.value.status == 507 and refused.value.extra["used_bytes"] == used
        assert statements  # near it: the pages were counted
        session.execute(text("DELETE FROM blobs WHERE id <= 4"))
        session.commit()
        sizes = sum(f.stat().st_size for f in (tmp_path / "q.db", tmp_path / "q.db-wal") if f.exists())
        assert files_bytes(session) == sizes >= used  # the files keep their size, the pages are free
        check_quota(session, used + BLOB // 2, BLOB)  # deleted data frees room
    assert files_bytes(Session(create_engine("sqlite://"))) == float("inf")
    with Database(f"sqlite:///{tmp_path / 'q.db'}").session() as session:  # the service's engine: a URI
        sizes = sum(f.stat().st_size for f in (tmp_path / "q.db", tmp_path / "q.db-wal") if f.exists())
        assert files_bytes(session) == sizes >= used


def test_plans_fill_the_quota_then_507_until_plans_are_deleted(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    with Session(create_engine(f"sqlite:///{stack.db_path}")) as session:
        used = database_bytes(session)
    stack.env["SPACEARM_STORAGE_QUOTA_BYTES"] = str(used + 400 * 1024)
    stack.start_api()
    body = {"robot_id": "table1", "task": PAPER_TASK, "replay": False}
    with stack.client() as client:
        stored: list[str] = []
        for _ in range(40):
            r = client.post("/v1/plans", params={"fields": ""}, json=body)
            if r.status_code != 201:
                break
            stored.append(r.json()["id"])
        assert r.status_code == 507, r.text
        problem = r.json()
        assert problem["quota_bytes"] == used + 400 * 1024 and problem["used_bytes"] <= problem["quota_bytes"]
        assert "delete plans or jobs" in problem["detail"]
        assert 5 <= len(stored) < 40
        for plan_id in stored[: len(stored) // 2]:
            assert client.delete(f"/v1/plans/{plan_id}").status_code == 204
        assert client.post("/v1/plans", params={"fields": ""}, json=body).status_code == 201
