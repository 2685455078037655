"""Start-up: the API loads the engine's kernels in the background; liveness answers at once,
readiness only once they are in (or says why they failed)."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

import engine
from service.app import create_app
from service.infra.migrate import upgrade
from service.infra.settings import Settings


def _app(tmp_path: Path, freeze_heap: bool = False) -> TestClient:
    url = f"sqlite:///{tmp_path / 'startup.db'}"
    upgrade(url, "head")
    app = create_app(Settings(database_url=url), freeze_heap=freeze_heap)
    return TestClient(app, base_url="http://localhost")  # an allowed Host


def test_ready_only_once_the_kernels_are_loaded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    gate = threading.Event()
    monkeypatch.setattr(engine, "warm_up", lambda: float(gate.wait(30)))
    with _app(tmp_path) as client:
        assert client.get("/healthz").status_code == 200
        loading = client.get("/readyz")
        assert loading.status_code == 503 and loading.json() == {"status": "unavailable", "kernels": "loading"}
        gate.set()
        deadline = time.monotonic() + 10
        while client.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert client.get("/readyz").json()["kernels"] == "ok"


def test_a_failed_kernel_load_keeps_the_api_unready(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def broken() -> float:
        raise RuntimeError("no writable numba cache")

    monkeypatch.setattr(engine, "warm_up", broken)
    with _app(tmp_path) as client:
        deadline = time.monotonic() + 10
        while (body := client.get("/readyz").json()).get("kernels") == "loading":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert body["status"] == "unavailable" and body["kernels"] == "failed: RuntimeError: no writable numba cache"
        assert client.get("/healthz").status_code == 200


def test_a_served_api_freezes_its_start_up_objects_before_it_is_ready(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``spacearm serve`` (``freeze_heap``) takes the start-up's objects out of the garbage
    collector's full collections before it says it is ready, and turns the collector back on
    (the command turned it off for its start-up); an app made without it (tests, embedding)
    leaves the collector alone."""
    monkeypatch.setattr(engine, "warm_up", lambda: 0.0)
    before = gc.get_freeze_count()
    try:
        with _app(tmp_path) as client:
            _wait_ready(client)
            assert gc.get_freeze_count() == before and gc.isenabled()
        gc.disable()  # as `spacearm serve` does before its imports
        with _app(tmp_path, freeze_heap=True) as client:
            _wait_ready(client)
            assert gc.get_freeze_count() > before
            assert gc.isenabled()
            assert client.get("/healthz").status_code == 200
    finally:
        gc.enable()
        gc.unfreeze()  # the test process's objects go back to the collector


def test_a_failed_kernel_load_turns_the_collector_back_on(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The collector is back on once the start-up ends, whether it ended well or not."""

    def broken() -> float:
        raise RuntimeError("no writable numba cache")

    monkeypatch.setattr(engine, "warm_up", broken)
    gc.disable()
    try:
        with _app(tmp_path, freeze_heap=True) as client:
            deadline = time.monotonic() + 10
            while client.get("/readyz").json()["kernels"] == "loading":
                assert time.monotonic() < deadline
                time.sleep(0.01)
            assert gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()


def _wait_ready(client: TestClient) -> None:
    deadline = time.monotonic() + 10
    while client.get("/readyz").status_code != 200:
        assert time.monotonic() < deadline
        time.sleep(0.01)


def test_the_start_up_rehearsal_and_route_visits_run_clean(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The start-up rehearses a plan request (insert, the event loop's read statement, rolled
    back) and visits each router's routes with ids that no row has: none of it is skipped or
    answers other than 200 or 404 (a visit that reached the figures' admission from the warm-up
    thread's own event loop would bind it to that loop)."""
    with caplog.at_level("INFO"), _app(tmp_path) as client:
        deadline = time.monotonic() + 60
        while client.get("/readyz").status_code != 200:
            assert time.monotonic() < deadline
            time.sleep(0.05)
    messages = [record.getMessage() for record in caplog.records]
    assert any("engine kernels ready" in m for m in messages), messages
    assert not [m for m in messages if "rehearsal" in m], messages


NO_KERNEL_SCRIPT = """
import json, sys
import service.app, service.worker, service.run
from service.cli import main
sys.argv = ["spacearm", "migrate"]
try:
    main()
except SystemExit as exc:
    assert not exc.code, exc.code
from engine.kernels.jit import KERNELS
from engine.warmup import kernel_name
print(json.dumps([kernel_name(k) for k in KERNELS if k.overloads]))
"""


def test_importing_the_service_and_migrating_load_no_kernel(tmp_path: Path) -> None:
    """At a first start, ``spacearm run``'s API and worker import the service while ``spacearm
    compile`` fills the kernel cache, and the migration runs beside it: a kernel called at import
    (the API's example quaternion was one) was compiled by each of the three at once, about 1.5 s
    of CPU each taken from the compilation. Nothing of it loads or compiles a kernel now."""
    env = {**os.environ, "SPACEARM_DATABASE_URL": f"sqlite:///{tmp_path / 'first.db'}"}
    done = subprocess.run([sys.executable, "-c", NO_KERNEL_SCRIPT], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert json.loads(done.stdout.strip().splitlines()[-1]) == []


def test_a_worker_stopped_during_its_warm_up_polls_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A stop (SIGTERM from ``spacearm run`` refusing to start) during the worker's warm-up: it
    said it was stopping, then logged that it was polling (a new-user trial found the two lines
    confusing); it now stops before the polling line."""
    import service.worker

    stop = threading.Event()

    def warm() -> float:
        stop.set()  # the signal handler's doing, as the kernels load
        return 0.0

    monkeypatch.setattr(service.worker, "warm_up", warm)
    url = f"sqlite:///{tmp_path / 'worker.db'}"
    upgrade(url, "head")
    with caplog.at_level("INFO", logger="spacearm.worker"):
        assert service.worker.run_worker(Settings(database_url=url), shutdown=stop) == 0
    assert "worker stopped before it polled" in caplog.text and "polling" not in caplog.text
