"""WAL checkpoints off the request path (:mod:`service.infra.checkpoint`): the API's commits leave
the log to the checkpoint thread, which copies it into the database file whenever it changed, and
says once (not at every look) when it cannot; past a backstop the commits checkpoint, so that the
log starts over under a steady stream of commits."""

from __future__ import annotations

import logging
import sqlite3
import threading
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text

from service.app import create_app
from service.infra.checkpoint import BACKSTOP_PAGES, Checkpointer
from service.infra.db import Database
from service.infra.migrate import upgrade
from service.infra.settings import Settings
from tests.service.conftest import PAPER_TASK, wait_for

PAGE = 4096
#: SQLite checkpoints in the commit that takes the log past 1,000 pages (wal_autocheckpoint).
AUTOCHECKPOINT_BYTES = 1000 * (PAGE + 24)


def new_database(path: Path) -> None:
    with sqlite3.connect(path) as conn:
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("CREATE TABLE blobs (data BLOB)")


def write(db: Database, commits: int, size: int = 4 * PAGE) -> None:
    for _ in range(commits):
        with db.connection() as conn:
            conn.execute(text("INSERT INTO blobs VALUES (randomblob(:n))"), {"n": size})


def test_the_apis_commits_leave_checkpoints_to_the_thread(tmp_path: Path) -> None:
    """300 commits of 5 pages: SQLite's own checkpoints keep the log under 1,000 pages (the
    control); with background checkpoints the log holds them all until the thread copies them into
    the database file, and then it has nothing to do until the next commit."""
    sizes = {}
    for background in (False, True):
        path = tmp_path / f"{background}.db"
        new_database(path)
        db = Database(f"sqlite:///{path}", background_checkpoints=background)
        held = db.engine.connect()  # keeps the log when the writing connection closes
        try:
            write(db, 300)
            wal = path.with_name(path.name + "-wal")
            sizes[background] = wal.stat().st_size
            if background:
                assert path.stat().st_size < 300 * 4 * PAGE  # nothing copied yet
                checkpointer = Checkpointer(path)
                assert checkpointer.step()
                assert path.stat().st_size >= 300 * 4 * PAGE  # copied into the database file
                assert not checkpointer.step()  # the log has not changed since
                write(db, 1)
                assert checkpointer.step()
            count = held.execute(text("SELECT count(*) FROM blobs")).scalar()
            assert count == (301 if background else 300)
        finally:
            held.close()
            db.dispose()
    assert sizes[False] <= 1.1 * AUTOCHECKPOINT_BYTES < 1.3 * AUTOCHECKPOINT_BYTES < sizes[True]


def test_the_log_starts_over_under_a_steady_stream_of_commits(tmp_path: Path) -> None:
    """1,600 commits of 5 pages while the thread checkpoints every 10 ms: every checkpoint ended
    with new frames appended during it, SQLite never started the log over, and it grew by all of
    them (33 MB); the commits' backstop keeps it under its 4,000 pages."""
    path = tmp_path / "steady.db"
    new_database(path)
    db = Database(f"sqlite:///{path}", background_checkpoints=True)
    checkpointer = Checkpointer(path, interval_s=0.01)
    checkpointer.start()
    try:
        write(db, 1600)
        largest = path.with_name(path.name + "-wal").stat().st_size  # a log file never shrinks while open
    finally:
        checkpointer.stop()
        db.dispose()
    assert largest <= 1.1 * BACKSTOP_PAGES * (PAGE + 24), largest


def test_a_checkpoint_that_fails_is_said_once_and_tried_again(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "gone.db"
    new_database(path)
    db = Database(f"sqlite:///{path}", background_checkpoints=True)
    held = db.engine.connect()
    try:
        write(db, 3)
        path.rename(tmp_path / "moved.db")  # the log stays, the file is gone: no connection opens
        checkpointer = Checkpointer(path)
        with caplog.at_level(logging.WARNING, logger="spacearm.checkpoint"):
            assert not checkpointer.step()
            assert not checkpointer.step()
        assert len([r for r in caplog.records if "WAL checkpoint" in r.getMessage()]) == 1
        (tmp_path / "moved.db").rename(path)
        assert checkpointer.step()
    finally:
        held.close()
        db.dispose()


def test_the_api_runs_the_thread_and_its_connections_do_not_checkpoint(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'api.db'}"
    upgrade(url, "head")
    app = create_app(Settings(database_url=url))
    with TestClient(app, base_url="http://localhost") as client:
        wait_for(app.state.kernels.ready.is_set, timeout=300)
        assert "wal-checkpoint" in {t.name for t in threading.enumerate()}
        with app.state.db.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA wal_autocheckpoint").scalar() == BACKSTOP_PAGES
        body = {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "adaptive"}, "replay": False}
        assert client.post("/v1/plans", json=body).status_code == 201
    assert "wal-checkpoint" not in {t.name for t in threading.enumerate()}
