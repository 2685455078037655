"""The command line: ``--version``, ``--help`` for every option, and ``spacearm run`` (what
``make run`` calls) as a real process: the URL only once ``/readyz`` answers, on the port from
``SPACEARM_PORT``, Ctrl-C stopping the API and the worker, a clear message when the API dies."""

from __future__ import annotations

import argparse
import asyncio
import gc
import json
import os
import queue
import re
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from importlib.metadata import version
from pathlib import Path

import httpx
import pytest

from service.cli import build_parser
from service.infra.settings import Settings
from tests.service.conftest import ROOT, free_port


def spacearm(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "service", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )


def test_version_is_the_package_version() -> None:
    done = spacearm("--version")
    assert done.returncode == 0
    assert done.stdout.strip() == f"spacearm {version('spacearm')}"


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def test_every_option_has_help_with_its_default() -> None:
    parser = build_parser()
    commands = _subparsers(parser)
    assert set(commands) == {"migrate", "compile", "serve", "worker", "run", "plan"}
    for name, sub in commands.items():
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and "default" in action.help, (name, action.option_strings)


def test_help_lists_commands_options_and_environment() -> None:
    top = spacearm("--help")
    assert top.returncode == 0
    for command in ("migrate", "serve", "worker", "run"):
        assert command in top.stdout
    for field in Settings.model_fields:  # every setting, with its variable
        assert f"SPACEARM_{field.upper()}" in top.stdout
    run = spacearm("run", "--help")
    assert run.returncode == 0
    for text in ("--host", "--port", "--workers", "--ready-timeout", "--log-format", "--verbose", "$SPACEARM_PORT", "8000"):
        assert text in run.stdout, text


def test_a_bad_setting_is_a_line_naming_the_variable_and_an_empty_optional_one_is_none(tmp_path: Path) -> None:
    """An invalid SPACEARM_* value was a pydantic traceback; an empty optional number (the
    documented way to turn the storage quota off) failed to parse."""
    env = {**os.environ, "SPACEARM_DATABASE_URL": f"sqlite:///{tmp_path / 'x.db'}", "SPACEARM_PORT": "abc"}
    bad = spacearm("migrate", env=env)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr
    assert "spacearm: SPACEARM_PORT='abc': Input should be a valid integer" in bad.stderr
    for empty in ("", "none", "None"):
        settings = Settings(**{"storage_quota_bytes": empty, "retention_days": empty, "db_pool_size": empty})  # type: ignore[arg-type]
        assert (settings.storage_quota_bytes, settings.retention_days, settings.db_pool_size) == (None, None, None)
    assert Settings.model_fields["storage_quota_bytes"].default == 10 * 2**30  # unset: the default, 10 GiB


def test_migrate_keeps_alembic_quiet_unless_asked(tmp_path: Path) -> None:
    def migrate(name: str, *args: str, **env: str) -> str:
        inherited = {k: v for k, v in os.environ.items() if k != "SPACEARM_LOG_LEVEL"}
        environ = {**inherited, "SPACEARM_DATABASE_URL": f"sqlite:///{tmp_path / name}", **env}
        done = spacearm("migrate", *args, env=environ)
        assert done.returncode == 0, done.stderr
        assert done.stdout.strip() == f"database sqlite:///{tmp_path / name} at head"
        return done.stderr

    assert "alembic" not in migrate("quiet.db")
    for stderr in (migrate("flag.db", "--verbose"), migrate("debug.db", SPACEARM_LOG_LEVEL="debug")):
        assert "INFO alembic.runtime.migration: Running upgrade  -> 0001" in stderr


def test_make_run_installs_the_runtime_only_and_calls_spacearm_run() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}  # not under `make test`'s
    plan = subprocess.run(
        ["make", "--no-print-directory", "-n", "-B", "run"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60
    )
    assert plan.returncode == 0, plan.stderr
    assert "pip install --quiet -e .\n" in plan.stdout and "[test]" not in plan.stdout
    assert plan.stdout.strip().splitlines()[-1].startswith(".venv/bin/spacearm run")


class Run:
    """``spacearm run`` with its stdout and stderr merged, read line by line in a thread."""

    def __init__(self, directory: Path, port: int, *args: str) -> None:
        env = {
            **os.environ,
            "SPACEARM_DATABASE_URL": f"sqlite:///{directory / 'spacearm.db'}",
            "SPACEARM_PORT": str(port),
            "SPACEARM_WORKER_POLL_SECONDS": "0.1",
            "PYTHONUNBUFFERED": "1",
        }
        env.pop("SPACEARM_HOST", None)
        self.popen = subprocess.Popen(
            [sys.executable, "-m", "service", "run", *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self.ended = False
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def until(self, text: str, timeout: float = 300.0) -> str | None:
        """The first line containing ``text`` (None if the output ended first)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=1.0)
            except queue.Empty:
                continue
            if line is None:
                self.ended = True
                return None
            self.seen.append(line)
            if text in line:
                return line
        raise AssertionError(f"no line with {text!r} within {timeout} s:\n" + "\n".join(self.seen))

    def rest(self) -> str:
        self.popen.wait(60)
        while not self.ended:
            line = self.lines.get(timeout=10)
            if line is None:
                self.ended = True
            else:
                self.seen.append(line)
        return "\n".join(self.seen)

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
            self.popen.wait(10)


@pytest.fixture
def runs() -> Iterator[list[Run]]:
    started: list[Run] = []
    yield started
    for r in started:
        r.stop()


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_run_prints_the_url_once_ready_and_ctrl_c_stops_everything(tmp_path: Path, runs: list[Run]) -> None:
    port = free_port()
    run = Run(tmp_path, port)
    runs.append(run)
    url_line = run.until("spacearm API on")
    assert url_line is not None, "\n".join(run.seen)
    assert f"http://127.0.0.1:{port}" in url_line
    # The URL line comes after the API said its kernels were in (the API logs that before /readyz
    # can answer 200, and both processes write to the same pipe) ...
    kernels = [i for i, line in enumerate(run.seen) if "spacearm.api: engine kernels ready" in line]
    assert kernels and kernels[0] < len(run.seen) - 1, "\n".join(run.seen)
    # ... after the database was migrated, and the API answers at once.
    assert any("at head" in line for line in run.seen[: kernels[0]])
    # The API's start-up is signalled through a pipe: one /readyz (the launcher's check) and no 503s
    readyz = [line for line in run.seen if '"GET /readyz' in line]
    assert len(readyz) == 1 and " 200" in readyz[0], "\n".join(run.seen)
    # The API binds (uvicorn prints its address) only after the migration: its imports overlap it
    uvicorn_url = next(i for i, line in enumerate(run.seen) if "Uvicorn running on" in line)
    assert any("at head" in line for line in run.seen[:uvicorn_url])
    assert httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=5).status_code == 200
    assert httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=5).status_code == 200
    assert not any("alembic" in line.lower() for line in run.seen)  # Alembic stays quiet
    # The launcher only watches its children: no numpy, numba or SQLAlchemy in it (issue 21: lean processes)
    maps = Path(f"/proc/{run.popen.pid}/maps").read_text()
    assert not any(name in maps for name in ("numpy", "numba", "sqlalchemy")), "the launcher loaded a heavy library"
    rss_mib = (
        next(
            int(line.split()[1])
            for line in Path(f"/proc/{run.popen.pid}/status").read_text().splitlines()
            if line.startswith("VmRSS")
        )
        / 1024
    )
    print(f"\nspacearm run launcher: {rss_mib:.0f} MiB")
    assert rss_mib <= 60.0
    # The worker runs at a lower CPU priority than the API (a GA generation yields to requests)
    niceness, child_maps = {}, {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                command = (entry / "cmdline").read_bytes().split(b"\0")
                if int(fields[1]) == run.popen.pid:
                    name = b"worker" if b"worker" in command else b"serve" if b"serve" in command else b"?"
                    niceness[name] = int(fields[16])
                    child_maps[name] = (entry / "maps").read_text()
            except OSError:
                continue
    assert niceness[b"worker"] == niceness[b"serve"] + 5, niceness
    # The migration seeded the new database's presets: neither the API nor the worker built the URDF
    # presets, whose parser brings trimesh and its libraries (about 60 MiB that would stay)
    for name, maps in child_maps.items():
        assert not any(library in maps for library in ("shapely", "manifold3d", "rtree")), name
    robots = httpx.get(f"http://127.0.0.1:{port}/v1/robots", timeout=5).json()["items"]
    assert {"table1", "table1-geometry", "arm7", "arm3"} <= {robot["id"] for robot in robots}

    run.popen.send_signal(signal.SIGINT)
    assert run.popen.wait(60) == 0
    output = run.rest()
    assert "signal 15: stopping" in output  # the worker got one SIGTERM
    assert "Shutting down" in output and "Finished server process" in output  # uvicorn's graceful exit
    assert "force" not in output.lower()
    assert not _port_open(port)


def healthz_count(counter: Path, folder: Path) -> float:
    """The ``GET /healthz`` 200s one API process counted (its counter file, read alone)."""
    from prometheus_client import CollectorRegistry
    from prometheus_client.multiprocess import MultiProcessCollector

    folder.mkdir()
    shutil.copy(counter, folder / counter.name)
    registry = CollectorRegistry()
    MultiProcessCollector(registry, path=str(folder))
    labels = {"method": "GET", "route": "/healthz", "status": "200"}
    return registry.get_sample_value("spacearm_http_requests_total", labels) or 0.0


def test_run_puts_several_api_processes_behind_one_port_with_summed_metrics(tmp_path: Path, runs: list[Run]) -> None:
    """``--api-processes 2``: both bind the port, connections reach both, and a scrape answered by
    either counts every request (prometheus-client's multiprocess mode); the shared folder of a
    run that made it is removed at the end, and a given one is emptied of an earlier run's files."""
    port = free_port()
    shared = tmp_path / "metrics"
    shared.mkdir()
    (shared / "counter_1.db").write_bytes(b"stale")  # an earlier run's: would add to this run's counts
    os.environ["PROMETHEUS_MULTIPROC_DIR"] = str(shared)
    try:
        run = Run(tmp_path, port, "--workers", "0", "--api-processes", "2")
    finally:
        del os.environ["PROMETHEUS_MULTIPROC_DIR"]
    runs.append(run)
    url_line = run.until("spacearm API on")
    assert url_line is not None and "(2 processes)" in url_line, "\n".join(run.seen)
    served = 0
    for _ in range(60):  # a connection each: the kernel spreads them over the two sockets
        with httpx.Client(base_url=f"http://127.0.0.1:{port}") as client:
            assert client.get("/healthz").status_code == 200
            served += 1
    counters = sorted(shared.glob("counter_*.db"))
    assert len(counters) == 2 and shared / "counter_1.db" not in counters  # the stale file is gone
    # a request is counted as its response ends: the last one may still be on its way
    answered: list[float] = []
    for attempt in range(50):
        answered = [healthz_count(counter, tmp_path / f"{counter.stem}-{attempt}") for counter in counters]
        if sum(answered) == served:
            break
        time.sleep(0.1)
    assert sum(answered) == served and min(answered) > 0, answered  # both processes answered
    for _ in range(2):  # whichever process answers the scrape counts all of them
        text = httpx.get(f"http://127.0.0.1:{port}/metrics", timeout=5).text
        counted = next(
            float(line.rsplit(" ", 1)[1])
            for line in text.splitlines()
            if line.startswith('spacearm_http_requests_total{method="GET",route="/healthz",status="200"}')
        )
        assert counted == served
        assert "spacearm_http_requests_in_progress 1.0" in text  # this scrape, in either process
    run.popen.send_signal(signal.SIGINT)
    assert run.popen.wait(60) == 0
    assert run.rest().count("Finished server process") == 2
    assert not _port_open(port)
    assert shared.is_dir()  # given: kept


def test_the_port_api_processes_share_answers_without_nagles_delay() -> None:
    """The socket several API processes bind (``shared_port_socket``) gives connections on which
    asyncio turns Nagle's algorithm off (``TCP_NODELAY``), as on the socket uvicorn binds itself:
    asyncio does so only for a socket that names ``IPPROTO_TCP``, and without it a response's body
    waited behind its headers for the client's delayed ACK (a kept-alive client's reads took 44 ms)."""
    from service.infra.server import shared_port_socket

    async def nodelay_of_an_accepted_connection() -> int:
        loop = asyncio.get_running_loop()
        accepted: asyncio.Future[int] = loop.create_future()

        class Accepting(asyncio.Protocol):
            def connection_made(self, transport: asyncio.BaseTransport) -> None:
                sock = transport.get_extra_info("socket")
                accepted.set_result(sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY))

        port = free_port()
        server = await loop.create_server(Accepting, sock=shared_port_socket("127.0.0.1", port))
        async with server:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            try:
                return await asyncio.wait_for(accepted, 10)
            finally:
                writer.close()

    assert asyncio.run(nodelay_of_an_accepted_connection()) != 0


def test_run_says_why_when_the_api_dies_before_it_is_ready(tmp_path: Path, runs: list[Run]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        run = Run(tmp_path, port, "--log-format", "json")
        runs.append(run)
        assert run.until("spacearm API on") is None
        assert run.popen.wait(60) == 1
    # --log-format json: every line of the output is a JSON object, spacearm run's own included
    entries = [json.loads(line) for line in run.rest().splitlines()]
    messages = [(e["logger"], e["level"], e["message"]) for e in entries]
    assert any(
        logger == "spacearm.run" and level == "ERROR" and re.match(r"spacearm run: the API process exited with code [1-9]", m)
        for logger, level, m in messages
    ), messages
    assert any(logger == "uvicorn.error" and "address already in use" in m for logger, _, m in messages)
    assert ("spacearm.worker", "INFO", "signal 15: stopping after the current generation") in messages  # stopped too
    # migrated by a child `spacearm migrate`: the launcher imports neither the database nor the engine
    assert ("spacearm.migrate", "INFO", f"database sqlite:///{tmp_path / 'spacearm.db'} at head") in messages


def test_several_api_processes_refuse_a_port_in_use(tmp_path: Path, runs: list[Run]) -> None:
    """SO_REUSEPORT would let them share a port with another program's (or another run's) socket
    that set it too; the launcher checks the port is free first."""
    with socket.socket() as taken:
        taken.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        run = Run(tmp_path, port, "--api-processes", "2", "--workers", "0")
        runs.append(run)
        assert run.popen.wait(60) == 1
    output = run.rest()
    assert f"spacearm run: cannot bind 127.0.0.1:{port}" in output and "Uvicorn running" not in output, output


def test_run_stops_the_api_and_the_worker_when_the_migration_fails(tmp_path: Path, runs: list[Run]) -> None:
    """The API and the worker wait at their gate while the database is migrated: a migration that
    refuses (here: a database holding another application's table) ends the run with its exit
    code, and neither child ever binds the port or claims a job."""
    port = free_port()
    with sqlite3.connect(tmp_path / "spacearm.db") as foreign:
        foreign.execute("create table invoices (id integer primary key)")
    run = Run(tmp_path, port)
    runs.append(run)
    assert run.until("spacearm API on") is None
    assert run.popen.wait(60) != 0
    output = run.rest()
    assert "spacearm migrate: the database has tables that are not spacearm's (invoices)" in output, output
    assert "Uvicorn running" not in output and "polling" not in output, output
    assert not _port_open(port)


def test_compile_says_when_the_kernels_are_compiled_and_reports_progress() -> None:
    """``spacearm compile`` (what ``make test``, ``spacearm run`` and the Docker image run): the
    suite's kernels were compiled before it started, so it has nothing to do; ``--force`` runs
    every part in its own process (loading from the cache here) and says how far it is."""
    done = spacearm("compile")
    assert done.returncode == 0, done.stderr
    assert "engine kernels: compiled already for this CPU" in done.stdout
    forced = spacearm("compile", "--force", "--log-format", "json")
    assert forced.returncode == 0, forced.stderr
    messages = [json.loads(line)["message"] for line in forced.stderr.splitlines()]  # log records: stderr
    assert messages[0].startswith("compiling the engine's kernels for this CPU into"), messages
    assert "compiling kernels: 2 of 2 parts done after" in messages[-2], messages
    assert re.fullmatch(r"engine kernels compiled in \d+ s", messages[-1]), messages


def test_the_first_part_compiled_lets_the_children_start(tmp_path: Path) -> None:
    """``spacearm run`` on a machine with no core to spare starts the API and the workers (their
    imports) once the first of ``spacearm compile``'s parts has ended, which the compilation says
    through a pipe (:data:`service.run.PROGRESS_FD`) and :func:`service.run.prepare_in_children`
    passes on, once. Here the cache is the suite's without its marker, so the parts load the
    kernels instead of compiling them."""
    from engine.kernels.cache import marker_path, source_hash
    from engine.kernels.jit import CACHE_DIR
    from engine.warmup import PARTS
    from service.run import COMPILE_PARTS, prepare_in_children

    assert len(PARTS) == COMPILE_PARTS
    cache = tmp_path / "numba" / f"spacearm-{source_hash()}"
    shutil.copytree(CACHE_DIR, cache)
    marker_path(cache).unlink()
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
        "SPACEARM_DATABASE_URL": f"sqlite:///{tmp_path / 'first.db'}",
    }
    told: list[bool] = []
    assert prepare_in_children(env, threading.Event(), compile=True, on_first_part=lambda: told.append(True)) == 0
    assert told == [True]
    assert marker_path(cache).exists()


def test_serve_freezes_the_start_up_heap(monkeypatch: pytest.MonkeyPatch) -> None:
    """``spacearm serve`` is a process of its own: it turns the cyclic garbage collector off before
    its imports and asks the app to freeze its start-up objects and turn the collector back on
    (:class:`service.app.Kernels`); an app made any other way does not."""
    import service.app
    import service.cli
    import service.infra.server
    import service.run
    from service.run import GATE_FD

    made: list[bool] = []

    def create_app(settings: Settings, *, freeze_heap: bool = False) -> object:
        made.append(freeze_heap)
        return object()

    monkeypatch.setattr(service.app, "create_app", create_app)
    monkeypatch.setattr(service.run, "kernels_compiled", lambda: True)
    monkeypatch.setattr(service.infra.server, "serve", lambda *args: None)
    monkeypatch.setattr(service.cli, "configure", lambda *args, **kwargs: None)  # the test process's logging stays
    monkeypatch.delenv(GATE_FD, raising=False)
    assert gc.isenabled()
    try:
        assert service.cli.main(["serve", "--port", str(free_port())]) == 0
        assert not gc.isenabled()  # the app (here a stand-in that never starts) turns it back on
    finally:
        gc.enable()
    assert made == [True]


def test_serve_collects_while_starting_when_it_must_compile(monkeypatch: pytest.MonkeyPatch) -> None:
    """With the kernel cache incomplete, ``spacearm serve`` compiles the kernels itself: the
    collector stays on through its start-up (numba's compilation makes millions of objects in cycles)."""
    import service.app
    import service.cli
    import service.infra.server
    import service.run
    from service.run import GATE_FD

    monkeypatch.setattr(service.run, "kernels_compiled", lambda: False)
    monkeypatch.setattr(service.app, "create_app", lambda settings, *, freeze_heap=False: object())
    monkeypatch.setattr(service.infra.server, "serve", lambda *args: None)
    monkeypatch.setattr(service.cli, "configure", lambda *args, **kwargs: None)
    monkeypatch.delenv(GATE_FD, raising=False)
    try:
        assert service.cli.main(["serve", "--port", str(free_port())]) == 0
        assert gc.isenabled()
    finally:
        gc.enable()


def test_worker_collects_again_after_its_start_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """``spacearm worker`` turns the collector off before its imports; the worker turns it back on
    (and freezes its start-up objects) once the kernels are in, before it polls for jobs."""
    import service.cli
    import service.run
    import service.worker
    from service.run import GATE_FD

    seen: list[tuple[bool, int]] = []

    def warm_up() -> float:
        seen.append((gc.isenabled(), gc.get_freeze_count()))
        return 0.0

    class StopPollingError(Exception):
        pass

    def database(*args: object, **kwargs: object) -> None:
        seen.append((gc.isenabled(), gc.get_freeze_count()))
        raise StopPollingError  # the poll loop is not this test's

    monkeypatch.setattr(service.run, "kernels_compiled", lambda: True)
    monkeypatch.setattr(service.worker, "warm_up", warm_up)
    monkeypatch.setattr(service.worker, "Database", database)
    monkeypatch.setattr(service.cli, "configure", lambda *args, **kwargs: None)
    monkeypatch.setattr(signal, "signal", lambda *args: None)  # the test process's handlers stay
    monkeypatch.delenv(GATE_FD, raising=False)
    before = gc.get_freeze_count()
    try:
        with pytest.raises(StopPollingError):
            service.cli.main(["worker", "--once"])
    finally:
        gc.enable()
        gc.unfreeze()  # the test process's objects go back to the collector
    (off, frozen_then), (on, frozen_now) = seen
    assert not off and frozen_then == before
    assert on and frozen_now > before
