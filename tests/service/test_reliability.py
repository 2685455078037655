"""Reliability under overload and faults (issue 12), over real HTTP against uvicorn and worker
subprocesses and real SQLite files: load shedding (only 201 or 503 with ``Retry-After``, while
liveness keeps answering), an exhausted connection pool, a deleted, replaced, read-only or full
database answered with 503 and recovered from without a restart, workers that outlive a database
fault, HTTP methods and framing, secrets kept out of the access log, strict input, idempotency
keys, cancellation inside a generation and the job cost cap.

The measured figures are printed (``pytest -s``); no test asserts a duration."""

from __future__ import annotations

import contextlib
import copy
import errno
import json
import math
import os
import re
import shutil
import socket
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import sqlalchemy
from fastapi.testclient import TestClient

import engine
from engine.kernels.jit import CACHE_DIR, source_hash
from service.app import create_app
from service.infra import jsonio
from service.infra.db import is_database_fault, make_engine, unavailable_reason
from service.infra.migrate import upgrade
from service.infra.settings import Settings
from tests.service.conftest import PAPER_TASK, ROOT, Stack, free_port, job_body, wait_for, wait_status

PROBLEM = "application/problem+json"
NOBODY = 65534  # the unprivileged user a root test runs the API as (file permissions do not bind root)
SMALL_PLAN = {"robot_id": "table1", "task": PAPER_TASK, "replay": False}


def assert_problem(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body: dict[str, Any] = r.json()
    assert body["status"] == status and body["detail"]
    return body


def assert_unavailable(r: httpx.Response, *words: str) -> dict[str, Any]:
    """A 503 problem with an integer ``Retry-After`` of at least a second whose detail has every
    one of ``words``."""
    body = assert_problem(r, 503)
    assert re.fullmatch(r"[1-9][0-9]*", r.headers.get("retry-after", "")), r.headers
    for word in words:
        assert word in body["detail"], body
    return body


def fields_of(r: httpx.Response) -> list[str]:
    """The field paths of a 422 problem."""
    return [e["field"] for e in assert_problem(r, 422).get("errors") or []]


def preset_robot(client: httpx.Client) -> dict[str, Any]:
    """The parameters of the preset robot ``table1``."""
    params: dict[str, Any] = client.get("/v1/robots/table1").json()["parameters"]
    return params


def named(params: dict[str, Any], name: str) -> dict[str, Any]:
    """A robot body: ``params`` under another name."""
    return {**copy.deepcopy(params), "name": name}


def stored_robot_names(path: Path) -> set[str]:
    """Names of the robots (not presets) in the SQLite file at ``path``, read by sqlite3 itself."""
    con = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        return {name for (name,) in con.execute("SELECT name FROM robots WHERE NOT preset")}
    finally:
        con.close()


# --- /healthz polled from a process of its own, so the test's client threads do not delay it

POLLER = r"""
import json, sys, threading, time
import httpx
url, interval = sys.argv[1], float(sys.argv[2])
stop = threading.Event()
rows = []
def poll():
    with httpx.Client(base_url=url, timeout=60) as c:
        while not stop.is_set():
            start = time.monotonic()  # CLOCK_MONOTONIC: the test's clock too
            try:
                status = c.get("/healthz").status_code
            except httpx.HTTPError as exc:
                status = type(exc).__name__
            rows.append((status, start, time.monotonic()))
            if len(rows) == 1:
                print("polling", flush=True)
            stop.wait(interval)
thread = threading.Thread(target=poll)
thread.start()
sys.stdin.read()  # until the test closes stdin
stop.set()
thread.join()
print(json.dumps(rows))
"""


@dataclass
class HealthLog:
    """The polls of ``/healthz``: status (or the client's exception), start and end (``time.monotonic``)."""

    rows: list[tuple[int | str, float, float]] = field(default_factory=list)

    @property
    def statuses(self) -> Counter[int | str]:
        return Counter(status for status, _, _ in self.rows)

    def answered_within(self, start: float, end: float) -> int:
        """How many polls were sent after ``start`` and answered 200 before ``end``."""
        return sum(status == 200 and start <= sent and done <= end for status, sent, done in self.rows)

    def summary(self) -> str:
        lat = np.array([done - sent for _, sent, done in self.rows]) * 1e3
        return (
            f"{len(lat)} /healthz polls, statuses {dict(self.statuses)}, latency ms: median {np.median(lat):.1f}, "
            f"p99 {np.percentile(lat, 99):.1f}, max {lat.max():.1f}"
        )


@contextlib.contextmanager
def health_polled(url: str, interval_s: float = 0.02) -> Iterator[HealthLog]:
    """``GET /healthz`` every ``interval_s`` from the first poll's answer (the block starts after
    it) to the end of the block; the polls are in the yielded log once the block ends."""
    log = HealthLog()
    proc = subprocess.Popen(
        [sys.executable, "-c", POLLER, url, str(interval_s)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdin is not None
    try:
        assert proc.stdout.readline() == "polling\n"
        yield log
    finally:
        proc.stdin.close()  # stops the poller
        try:
            out = proc.stdout.read()
            proc.wait(timeout=120)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise
    log.rows = [(status, sent, done) for status, sent, done in json.loads(out)]


# --- overload: load shedding, liveness, large responses


def test_100_concurrent_plans_get_201_or_503_while_liveness_answers(stack: Stack) -> None:
    n = 100
    # 15,000 steps, replayed: about a second of a core each, and a 13 MB answer
    body = {"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 0.001}, "replay": True}
    barrier = threading.Barrier(n)

    def submit(_: int) -> tuple[httpx.Response, float, float]:
        with httpx.Client(base_url=stack.url, timeout=300) as c:
            barrier.wait()
            start = time.monotonic()
            r = c.post("/v1/plans", json=body)
            return r, start, time.monotonic()

    with health_polled(stack.url) as health, ThreadPoolExecutor(n) as pool:
        results = list(pool.map(submit, range(n)))

    codes = Counter(r.status_code for r, _, _ in results)
    print(f"\n100 concurrent plans: {dict(codes)}; {health.summary()}")
    for code in (201, 503):
        took = [end - start for r, start, end in results if r.status_code == code]
        if took:
            print(f"  {code}: answered in {min(took):.2f} to {max(took):.2f} s")
    assert set(codes) <= {201, 503}, codes
    assert codes[201] > 0 and codes[503] > 0, codes  # 100 > slots + queue: some were shed, some planned
    for r, _, _ in results:
        if r.status_code == 503:
            assert_unavailable(r, "too many plans")
    assert set(health.statuses) == {200}, health.statuses
    # liveness answered while plans were being computed (from the first request to the last plan),
    # not only before or after them
    sent = min(start for _, start, _ in results)
    planned = max(end for r, _, end in results if r.status_code == 201)
    answered = health.answered_within(sent, planned)
    print(f"  /healthz answered {answered} times while plans were computed")
    assert answered >= 10, health.rows
    with stack.client() as c:
        for r, _, _ in results:
            if r.status_code == 201:
                stored = c.get(r.headers["location"], params={"fields": ""})
                assert stored.status_code == 200 and stored.json()["id"] == r.headers["location"].rsplit("/", 1)[1]
        ready = c.get("/readyz")
        assert ready.status_code == 200, ready.text  # nothing left behind: the pool and the database are fine


def test_8_parallel_reads_of_a_large_plan_while_liveness_answers(stack: Stack, client: httpx.Client) -> None:
    task = {**PAPER_TASK, "dt_s": 0.00075}  # 20,000 steps
    created = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": task, "replay": False})
    assert created.status_code == 201, created.text
    location = created.headers["location"]
    barrier = threading.Barrier(8)

    def read(_: int) -> list[httpx.Response]:
        with httpx.Client(base_url=stack.url, timeout=300) as c:
            barrier.wait()
            return [c.get(location) for _ in range(3)]  # 3 in a row: a longer window for the polls

    with health_polled(stack.url) as health, ThreadPoolExecutor(8) as pool:
        start = time.monotonic()
        responses = [r for rs in pool.map(read, range(8)) for r in rs]
        end = time.monotonic()

    answered = health.answered_within(start, end)
    print(
        f"\n8 clients reading a {len(responses[0].content) / 2**20:.1f} MiB plan 3 times each in {end - start:.1f} s; "
        f"{health.summary()}; {answered} answered during the reads"
    )
    assert [r.status_code for r in responses] == [200] * 24
    assert len({r.content for r in responses}) == 1
    assert len(responses[0].json()["trajectory"]["t_s"]) == 20_001
    assert set(health.statuses) == {200}, health.statuses
    assert answered >= 5, health.rows


def test_large_bodies_are_encoded_in_pieces_to_the_same_bytes() -> None:
    """The plan body encoder that lets the event loop run between pieces writes what one orjson
    call writes: arrays split across pieces (at and off the piece boundary), NaN, empty arrays,
    nested objects, escaped keys."""
    rng = np.random.default_rng(7)
    rows = jsonio.ROWS_PER_PIECE
    value = {
        "id": "0" * 32,
        'quoted "key" é': {"a": 1.5, "b": None, "c": [1, 2]},
        "trajectory": {
            "t_s": rng.random(2 * rows),
            "joint_angles_deg": rng.standard_normal((2 * rows + 1, 6)) * 1e3,
            "det_gjm": np.where(rng.random(rows + 7) < 0.1, np.nan, rng.random(rows + 7)),
            "rotations": rng.random((rows + 1, 3, 3)),
            "empty": np.zeros((0, 4)),
            "short": rng.random((3, 2)),
        },
    }
    assert jsonio._has_large(value) and jsonio.dumps_large(value) == jsonio.dumps(value)
    assert not jsonio._has_large({**value, "trajectory": {"short": value["trajectory"]["short"]}})
    assert jsonio._has_large({"a": {"b": {"c": np.zeros(rows + 1)}}, "d": [np.zeros(rows + 1)]})


def test_json_columns_get_json_values() -> None:
    """What a JSON column stores: numpy arrays and scalars as lists and numbers, NaN and infinities
    as null, tuples as lists, keys as strings; the same where orjson cannot write a value (an
    integer beyond 64 bits, a column of an array) and the values are converted one by one."""
    value = {
        "a": np.array([1.0, np.nan, np.inf]),
        1: (np.float64(2.5), np.int64(3), np.bool_(True)),
        "b": [-math.inf, None, "x", {"c": math.nan}],
    }
    expected = {"a": [1.0, None, None], "1": [2.5, 3, True], "b": [None, None, "x", {"c": None}]}
    assert jsonio.clean(value) == expected
    assert jsonio.clean({**value, "big": 2**70}) == {**expected, "big": 2**70}
    column = np.arange(12.0).reshape(3, 4)[:, 1]
    assert jsonio.clean({**value, "column": column}) == {**expected, "column": [1.0, 5.0, 9.0]}
    assert type(jsonio.clean({"n": np.int64(3)})["n"]) is int


def test_an_exhausted_connection_pool_is_a_503_then_recovers(tmp_path: Path) -> None:
    """In process (the pool is held by the test): one pooled connection, held; a request that
    needs one waits 0.2 s for it, then gets a 503 with Retry-After."""
    url = f"sqlite:///{tmp_path / 'pool.db'}"
    upgrade(url, "head")
    app = create_app(Settings(database_url=url, db_pool_size=1, db_pool_timeout_s=0.2))
    with TestClient(app, base_url="http://localhost") as client:  # an allowed Host
        wait_for(app.state.kernels.ready.is_set, timeout=300)  # its rehearsal of a plan uses the pool too
        assert client.get("/v1/robots").status_code == 200
        held = app.state.db.engine.connect()
        try:
            assert_unavailable(client.get("/v1/robots"), "every database connection is in use")
            assert client.get("/healthz").status_code == 200
            assert client.get("/readyz").status_code == 200  # readiness has a connection of its own
        finally:
            held.close()
        listing = client.get("/v1/robots")
        assert listing.status_code == 200 and listing.json()["items"][0]["id"] == "table1"


# --- database faults


def test_a_refused_connection_is_a_database_fault_and_a_bad_statement_is_not(tmp_path: Path) -> None:
    """The drivers' own exceptions: psycopg's "connection refused" carries no SQLSTATE and SQLAlchemy
    does not call it a disconnect at connect time; the workers must still wait it out (they exited
    on it). SQLite's errors of the statement itself are the work's, not the database's."""
    refused = make_engine(f"postgresql+psycopg://nobody@127.0.0.1:{free_port()}/none?connect_timeout=5")
    try:
        with pytest.raises(sqlalchemy.exc.OperationalError) as caught:
            refused.connect()
    finally:
        refused.dispose()
    assert getattr(caught.value.orig, "sqlstate", None) is None and not caught.value.connection_invalidated
    assert unavailable_reason(caught.value) == "the database server cannot be reached"
    assert is_database_fault(caught.value)

    local = make_engine(f"sqlite:///{tmp_path / 'x.db'}", create=True)
    try:
        for statement in ("SELECT * FROM no_such_table", "SELEC 1"):
            with pytest.raises(sqlalchemy.exc.OperationalError) as caught, local.connect() as conn:
                conn.exec_driver_sql(statement)
            assert unavailable_reason(caught.value) is None and not is_database_fault(caught.value), statement
    finally:
        local.dispose()


def test_deleted_database_is_a_503_and_restored_or_replaced_without_restart(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.start_api()
    path = stack.db_path
    kept = path.with_name("kept.db")
    os.link(path, kept)  # the deleted file can be brought back: same file, same inode
    with stack.client() as c:
        table1 = preset_robot(c)
        assert c.post("/v1/robots", json=named(table1, "before")).status_code == 201
        path.unlink()  # as `rm spacearm.db`: the -wal and -shm files stay
        assert_unavailable(c.post("/v1/robots", json=named(table1, "while missing")), "missing")
        assert_unavailable(c.post("/v1/plans", json=SMALL_PLAN), "missing")
        assert_unavailable(c.get("/v1/robots"), "missing")
        ready = c.get("/readyz")
        assert ready.status_code == 503 and "missing" in ready.json()["database"], ready.text
        assert re.fullmatch(r"[1-9][0-9]*", ready.headers["retry-after"])
        assert c.get("/healthz").status_code == 200
        assert not path.exists()  # nothing created an empty database in its place

        os.link(kept, path)  # restored: the API takes writes again without a restart
        assert c.post("/v1/robots", json=named(table1, "after restore")).status_code == 201
        assert c.get("/readyz").status_code == 200
        assert stored_robot_names(path) == {"before", "after restore"}

        # replaced: the old database moved away with its -wal and -shm, a new one migrated at the path
        old = path.with_name("old.db")
        for suffix in ("", "-wal", "-shm"):
            if Path(f"{path}{suffix}").exists():
                Path(f"{path}{suffix}").rename(f"{old}{suffix}")
        kept.unlink()
        subprocess.run([sys.executable, "-m", "service", "migrate"], cwd=ROOT, env=stack.env, check=True, capture_output=True)
        listing = c.get("/v1/robots")  # the new file's: its presets only
        assert listing.status_code == 200, listing.text
        items = listing.json()["items"]
        assert "table1" in {r["id"] for r in items} and all(r["preset"] for r in items), listing.text
        assert c.post("/v1/robots", json=named(table1, "in the new file")).status_code == 201
        assert c.get("/readyz").status_code == 200
    assert stored_robot_names(path) == {"in the new file"}
    assert stored_robot_names(old) == {"before", "after restore"}  # no write went to the replaced file
    assert "was replaced: reconnecting" in stack.dir.joinpath("api.log").read_text()


def _chown_tree(top: Path, uid: int) -> None:
    os.chown(top, uid, uid)
    for directory, dirs, files in os.walk(top):
        for name in dirs + files:
            os.chown(os.path.join(directory, name), uid, uid)


def test_database_made_read_only_refuses_writes_with_503_and_recovers_without_restart() -> None:
    """The database file becomes read-only under the running API (for its user: as root, the API
    runs as ``nobody``, since permissions do not bind root): reads work, writes and readiness say
    read-only (even though the API's open connections could still write); once the file is
    writable again the next write succeeds, with the same API process."""
    root = os.geteuid() == 0
    if root and shutil.which("setpriv") is None:
        pytest.skip("running as root, whom file permissions do not bind, and setpriv (util-linux) is missing")
    base = Path(tempfile.mkdtemp(prefix="spacearm-ro-"))
    stack: Stack | None = None
    try:
        (base / "stack").mkdir()
        stack = Stack(base / "stack")
        db = stack.db_path
        prefix: tuple[str, ...] = ()
        if root:
            engine.warm_up()  # the compiled kernels are in the cache to copy
            cache = base / "numba"
            shutil.copytree(CACHE_DIR, cache / f"spacearm-{source_hash()}")  # nobody cannot write the tree's cache
            home = base / "home"
            home.mkdir()
            stack.env.update(NUMBA_CACHE_DIR=str(cache), HOME=str(home), MPLCONFIGDIR=str(home / "matplotlib"))
            _chown_tree(base, NOBODY)
            prefix = ("setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", "--")
        stack.start_api(prefix)
        with stack.client() as c:
            table1 = preset_robot(c)
            assert c.post("/v1/robots", json=named(table1, "writable")).status_code == 201
            files = [f for f in (db, Path(f"{db}-wal"), Path(f"{db}-shm")) if f.exists()]
            for f in files:  # as `chmod a-w spacearm.db*`
                f.chmod(0o444)
            if not root and os.access(db, os.W_OK):
                pytest.skip("this user can write a file with mode 0444 (a capability such as CAP_DAC_OVERRIDE)")
            ready = c.get("/readyz")
            assert ready.status_code == 503 and ready.json()["database"] == "the database is read-only", ready.text
            assert_unavailable(c.post("/v1/robots", json=named(table1, "read-only")), "read-only")
            assert_unavailable(c.post("/v1/plans", json=SMALL_PLAN), "read-only")
            listing = c.get("/v1/robots")
            assert listing.status_code == 200 and listing.json()["items"][0]["id"] == "table1"
            assert c.get("/v1/plans").status_code == 200
            assert c.get("/healthz").status_code == 200

            # the fault ends (`chmod u+w spacearm.db*`: SQLite gave any -wal or -shm it created
            # meanwhile the database's mode); the API is not restarted
            for f in {*files, *db.parent.glob(f"{db.name}-*")}:
                f.chmod(0o644)
            r = c.post("/v1/robots", json=named(table1, "writable again"))
            assert r.status_code == 201, r.text
            assert c.post("/v1/plans", json=SMALL_PLAN).status_code == 201
            assert c.get("/readyz").status_code == 200
        assert stack.api is not None and stack.api.popen.poll() is None
        assert stored_robot_names(db) == {"writable", "writable again"}
    finally:
        if stack is not None:
            stack.close()
        shutil.rmtree(base, ignore_errors=True)


def _fill(directory: Path) -> Path:
    """A file that takes every free byte of the file system of ``directory``."""
    filler = directory / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        for chunk in (b"\0" * 65536, b"\0" * 4096, b"\0"):
            try:
                while True:
                    os.write(fd, chunk)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
    finally:
        os.close(fd)
    return filler


def test_full_disk_is_a_503_and_writes_resume_when_space_is_freed(tmp_path: Path) -> None:
    """The database on a 2 MiB tmpfs the test mounts; the rest of it filled with a file. Deletions
    still work on the full disk (issue 22: a DELETE answered 503 too, so space could not be freed
    through the API): a plan is deleted, and a robot can be stored in its place."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs for the database needs root (CAP_SYS_ADMIN)")
    fs = tmp_path / "fs"
    fs.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(fs)], capture_output=True, text=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs for the database (needs CAP_SYS_ADMIN): {mounted.stderr.strip()}")
    stack: Stack | None = None
    try:
        (tmp_path / "stack").mkdir()
        stack = Stack(tmp_path / "stack", database_url=f"sqlite:///{fs / 'spacearm.db'}")  # the logs stay off the tmpfs
        stack.start_api()
        with stack.client() as c:
            table1 = preset_robot(c)
            assert c.post("/v1/robots", json=named(table1, "room")).status_code == 201
            plan = c.post("/v1/plans?fields=", json=SMALL_PLAN)
            assert plan.status_code == 201, plan.text
            filler = _fill(fs)
            stored = 0
            for i in range(2000):
                r = c.post("/v1/robots", json=named(table1, f"filling {i}"))
                if r.status_code != 201:
                    break
                stored += 1
            print(f"\ndisk full after {stored} more robots: {r.status_code} {r.text}")
            assert_unavailable(r, "disk is full")
            ready = c.get("/readyz")
            print(f"/readyz on a full disk: {ready.status_code} {ready.text}")
            assert ready.status_code == 503 and ready.json()["database"] == "the database's disk is full", ready.text
            assert c.get("/v1/robots", params={"limit": 1}).status_code == 200  # reads still work
            assert c.get("/healthz").status_code == 200
            deleted = c.delete(f"/v1/plans/{plan.json()['id']}")
            assert deleted.status_code == 204, deleted.text  # the disk reserve makes room for deletions
            after_delete = c.post("/v1/robots", json=named(table1, "in the deleted plan's place"))
            print(f"a deletion on the full disk: {deleted.status_code}; a robot stored after it: {after_delete.status_code}")
            assert after_delete.status_code == 201, after_delete.text

            filler.unlink()  # the fault ends; the API is not restarted
            after = c.post("/v1/robots", json=named(table1, "after freeing space"))
            assert after.status_code == 201, after.text
            assert c.post("/v1/plans", json=SMALL_PLAN).status_code == 201
            assert c.get("/readyz").status_code == 200
        assert stack.api is not None and stack.api.popen.poll() is None
    finally:
        if stack is not None:
            stack.close()
        subprocess.run(["umount", str(fs)], check=False)


def test_worker_outlives_a_missing_database_and_gives_its_job_back(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack(lease_seconds=3.0)
    path, away = stack.db_path, stack.db_path.with_name("away.db")
    worker_outlives_an_outage(stack, lambda: path.rename(away), lambda: away.rename(path), "missing")


def worker_outlives_an_outage(stack: Stack, go: Callable[[], object], come_back: Callable[[], object], word: str) -> None:
    """The database goes (``go``) twice under a running API and worker, once while the worker is
    idle and once while it runs a job: the API answers 503 with ``Retry-After`` (its detail says
    ``word``), the worker waits, gives the job back, and runs it to the end once the database is
    back (``come_back``); neither process exits or needs a restart."""
    stack.start_api()
    worker = stack.start_worker()

    def logged(text: str) -> int:
        return worker.log.read_text().count(text)

    with stack.client() as c:
        # idle: the worker polls a database that has gone, and waits for it with backoff
        first = c.post("/v1/tuning-jobs", json=job_body()).json()
        wait_status(c, first["id"], ("succeeded",), timeout=300)  # the worker is up and claiming
        go()
        wait_for(lambda: logged("the database is unavailable") >= 4 or worker.popen.poll() is not None, timeout=60)
        assert worker.popen.poll() is None, worker.log.read_text()[-3000:]
        assert_unavailable(c.get("/v1/robots"), word)
        assert_unavailable(c.post("/v1/plans", json=SMALL_PLAN), word)
        come_back()
        assert wait_for(lambda: c.get("/v1/robots").status_code == 200, timeout=30)  # the API recovers by itself

        # busy: a job running, another queued behind it; the database goes while the first runs
        running = c.post("/v1/tuning-jobs", json=job_body(population=8, generations=60, compare=False, dt_s=0.01)).json()
        wait_status(c, running["id"], ("running",))
        queued = c.post("/v1/tuning-jobs", json=job_body()).json()
        go()
        # the GA stops, and the worker tries to give the job back until the database answers
        giving_back = f"job {running['id']}: giving it back: the database is unavailable"
        wait_for(lambda: logged(giving_back) >= 3 or worker.popen.poll() is not None, timeout=60)
        assert worker.popen.poll() is None, worker.log.read_text()[-3000:]
        come_back()
        for job in (running, queued):
            done = wait_status(c, job["id"], ("succeeded", "failed", "cancelled"), timeout=120)
            assert done["status"] == "succeeded", done
        # given back (a fault is not the job's attempt), claimed again, run to the end
        assert c.get(f"/v1/tuning-jobs/{running['id']}").json()["attempts"] == 1
    assert logged(f"job {running['id']}: requeued") == 1 and logged(f"job {running['id']} claimed") == 2
    assert worker.popen.poll() is None and stack.api is not None and stack.api.popen.poll() is None
    print("\nworker log while the database was away:")
    print("\n".join(line for line in worker.log.read_text().splitlines() if "unavailable" in line or "requeued" in line))


# --- HTTP methods and framing, secrets in logs


def test_head_options_and_405_carry_the_complete_allow(client: httpx.Client) -> None:
    get, head = client.get("/v1/robots"), client.head("/v1/robots")
    assert head.status_code == 200 and head.content == b""
    assert head.headers["content-type"] == get.headers["content-type"]
    assert head.headers["content-length"] == get.headers["content-length"] == str(len(get.content))
    assert client.head("/healthz").status_code == 200

    options = client.options("/v1/plans")
    assert options.status_code == 204 and options.headers["allow"] == "GET, HEAD, POST, OPTIONS"
    assert_problem(client.options("/v1/no-such-thing"), 404)
    refused = client.delete("/v1/plans")
    assert_problem(refused, 405)
    assert refused.headers["allow"] == "GET, HEAD, POST, OPTIONS"

    # every documented path: OPTIONS lists exactly its documented methods (HEAD with GET, OPTIONS)
    order = ["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"]
    for template, operations in client.get("/openapi.json").json()["paths"].items():
        path = re.sub(r"\{[^}]+\}", "0" * 32, template)
        documented = {m.upper() for m in operations} | {"OPTIONS"} | ({"HEAD"} if "get" in operations else set())
        r = client.options(path)
        assert r.status_code == 204, (template, r.text)
        assert r.headers["allow"] == ", ".join(sorted(documented, key=order.index)), template


def _raw_http(port: int, request: bytes) -> bytes:
    """Send ``request`` as is (no client library would send a conflicting framing) and read the answer."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(request)
        answer = b""
        while chunk := s.recv(65536):
            answer += chunk
    return answer


def test_content_length_with_chunked_transfer_encoding_is_a_400(stack: Stack) -> None:
    body = b'{"robot_id": "table1"}'
    chunked = b"%x\r\n%s\r\n0\r\n\r\n" % (len(body), body)
    head = b"POST /v1/plans HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nConnection: close\r\n"
    both = _raw_http(stack.port, head + b"Content-Length: %d\r\nTransfer-Encoding: chunked\r\n\r\n" % len(body) + chunked)
    assert both.startswith(b"HTTP/1.1 400 "), both[:200]
    # the same request framed one way only is read (and refused for what it says: no task)
    assert _raw_http(stack.port, head + b"Transfer-Encoding: chunked\r\n\r\n" + chunked).startswith(b"HTTP/1.1 422 ")
    assert _raw_http(stack.port, head + b"Content-Length: %d\r\n\r\n" % len(body) + body).startswith(b"HTTP/1.1 422 ")


def test_secrets_in_query_strings_stay_out_of_the_access_log(stack: Stack, client: httpx.Client) -> None:
    names = ["api_key", "API_KEY", "token", "access_token", "client_secret", "password", "passwd", "auth", "session_id"]
    names += ["credentials"]
    secrets = {name: f"SECRET{i}X" for i, name in enumerate(names)}
    marker = uuid.uuid4().hex
    assert client.get("/v1/robots", params={**secrets, "marker": marker}).status_code == 200
    assert client.get("/v1/no-such-thing", params={"marker": marker + "b", "api_key": "SECRETY"}).status_code == 404
    log = stack.dir / "api.log"
    wait_for(lambda: marker + "b" in log.read_text())
    text = log.read_text()
    assert "SECRET" not in text
    line = next(line for line in text.splitlines() if f"marker={marker}" in line)
    assert line.count("=[redacted]") == len(names), line
    print(f"\naccess log line: {line}")


# --- strict input and idempotency keys


@pytest.mark.parametrize(
    ("path", "change", "field"),
    [
        ("/v1/plans", {"replay": 0}, "body.replay"),
        ("/v1/plans", {"replay": "true"}, "body.replay"),
        ("/v1/plans", {"task": {**PAPER_TASK, "duration_s": "15"}}, "body.task.duration_s"),
        ("/v1/plans", {"task": {**PAPER_TASK, "dt_s": 1e-306}}, "body.task.dt_s"),
        ("/v1/plans", {"colour": "red"}, "body.colour"),
        ("/v1/plans", {"task": {**PAPER_TASK, "speed": 1.0}}, "body.task.speed"),
        ("/v1/plans", {"method": {"name": "adaptive\x00"}}, "body.method.name"),
        ("/v1/tuning-jobs", {"tasks": [{**PAPER_TASK, "dt_s": 1e-306}]}, "body.tasks[0].dt_s"),
        ("/v1/tuning-jobs", {"ga": {"population": "8"}}, "body.ga.population"),
        ("/v1/tuning-jobs", {"compare_with_dls": 1}, "body.compare_with_dls"),
        ("/v1/tuning-jobs", {"objective": {"weights": [0.5, 0.5], "extra": 1}}, "body.objective.extra"),
    ],
)
def test_strict_input_is_a_422_naming_the_field(client: httpx.Client, path: str, change: dict[str, Any], field: str) -> None:
    base = SMALL_PLAN if path == "/v1/plans" else job_body()
    assert fields_of(client.post(path, json={**base, **change})) == [field]


def test_robot_id_and_robot_together_and_nul_in_names_are_422s(client: httpx.Client) -> None:
    robot = named(preset_robot(client), "inline")
    r = client.post("/v1/plans", json={**SMALL_PLAN, "robot": robot})
    assert fields_of(r) == ["body"] and "exactly one of robot_id" in r.json()["detail"], r.text
    r = client.post("/v1/tuning-jobs", json={**job_body(), "robot": robot})
    assert fields_of(r) == ["body"] and "exactly one of robot_id" in r.json()["detail"], r.text
    before = client.get("/v1/robots").json()["total"]
    assert fields_of(client.post("/v1/robots", json={**robot, "name": "arm\x00one"})) == ["body.name"]
    assert client.get("/v1/robots").json()["total"] == before  # nothing stored on SQLite either


@pytest.mark.parametrize("key", [b"", b"k" * 256, "clé".encode(), b"tab\there"], ids=["empty", "256-chars", "non-ascii", "tab"])
def test_bad_idempotency_keys_are_422s_naming_the_header(client: httpx.Client, key: bytes) -> None:
    before = client.get("/v1/tuning-jobs", params={"limit": 1}).json()["total"]
    r = client.post("/v1/tuning-jobs", json=job_body(), headers={b"Idempotency-Key": key})
    assert fields_of(r) == ["header.Idempotency-Key"], r.text
    assert client.get("/v1/tuning-jobs", params={"limit": 1}).json()["total"] == before


def test_idempotency_key_is_bound_to_the_request_body(client: httpx.Client) -> None:
    key = "k" * 254 + "~"  # 255 printable characters: the longest key
    body = job_body(population=4, generations=1, compare=False)
    first = client.post("/v1/tuning-jobs", json=body, headers={"Idempotency-Key": key})
    assert first.status_code == 202, first.text
    other = client.post("/v1/tuning-jobs", json={**body, "ga": {**body["ga"], "seed": 2}}, headers={"Idempotency-Key": key})
    problem = assert_problem(other, 422)
    assert problem["errors"][0]["field"] == "header.Idempotency-Key"
    assert "different request body" in problem["detail"] and first.json()["id"] in problem["detail"], problem
    # the same request written differently (keys in another order, defaults spelled out) is the same request
    same = dict(reversed(list({**body, "feedback_gain": 0.0, "ga": {**body["ga"], "crossover_probability": 0.8}}.items())))
    again = client.post("/v1/tuning-jobs", json=same, headers={"Idempotency-Key": key})
    assert again.status_code in (200, 202) and again.json()["id"] == first.json()["id"], again.text
    assert again.headers["location"] == first.headers["location"]


# --- job cost: cancellation inside a generation, the cap in joint-steps


def test_cancel_takes_effect_inside_a_long_generation(client: httpx.Client, stack: Stack) -> None:
    # 200 plans of 15,000 steps a generation: about 20 s of a core, far longer than a cancel may take
    body = job_body(population=200, generations=2, compare=False, dt_s=0.001)
    job = client.post("/v1/tuning-jobs", json=body).json()
    wait_status(client, job["id"], ("running",), timeout=120)
    time.sleep(0.5)  # well inside the evaluation of the initial population
    start = time.perf_counter()
    r = client.post(f"/v1/tuning-jobs/{job['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"] is True
    done = wait_status(client, job["id"], ("cancelled", "succeeded", "failed"), timeout=120)
    took = time.perf_counter() - start
    print(f"\ncancel inside a generation: cancelled {took:.2f} s after the request; progress {done['progress']}")
    assert done["status"] == "cancelled", done
    assert done["progress"]["generation"] == 0 and done["progress"]["evaluations"] == 0  # no generation was finished
    assert client.get(f"/v1/tuning-jobs/{job['id']}/result").status_code == 409
    assert all(w.popen.poll() is None for w in stack.workers)


def test_job_cost_is_capped_in_joint_steps(client: httpx.Client) -> None:
    robot = named(preset_robot(client), "twelve joints")
    twice = robot["links"] * 2  # each link with a name of its own
    robot["links"] = [{**link, "name": f"link{i + 1}", "joint_name": f"joint{i + 1}"} for i, link in enumerate(twice)]
    task = {**PAPER_TASK, "q0_deg": [10.0] * 12, "duration_s": 200.0, "dt_s": 0.01}  # 20,000 steps
    # 50 generations, with DLS; the GA alone (the refinement's plans would add to the sum)
    body = {"robot": robot, "tasks": [task], "method": "adaptive", "ga": {"population": 1000}, "refine": False}
    evaluations = 1000 * (50 + 1) * 2
    assert evaluations <= 200_000  # within the evaluation cap: the work is what is refused
    joint_steps = evaluations * (20_000 + 1) * 12
    r = client.post("/v1/tuning-jobs", json=body)
    problem = assert_problem(r, 422)
    print(f"\njob cost cap: {problem['detail']}")
    assert problem["errors"][0]["field"] == "body.ga"
    assert f"= {joint_steps:.3g} joint-steps, at most 7e+09 per job" in problem["detail"], problem
    # the phases named are this job's: the method tuned and the DLS baseline (compare_with_dls, on by default)
    assert "* 2 (phases: the method tuned, compare_with_dls) *" in problem["detail"], problem
