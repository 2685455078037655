"""A throwaway PostgreSQL cluster for the tests: ``tests/postgres/setup.sh`` makes sure the server
binaries exist (apt-get on a clean Debian machine), then ``initdb`` a cluster in a temp dir, start
it on a free port on 127.0.0.1 and on a unix socket in that dir, and stop it at the end (a test
with a cluster of its own may stop and start it in between: an outage).

PostgreSQL refuses to run as root: as root, initdb/pg_ctl run as the ``postgres`` OS user
(``runuser``) and the temp dir belongs to it. If PostgreSQL cannot be installed or started the
tests fail when ``CI=true`` and are skipped otherwise. ``SPACEARM_TEST_POSTGRES_URL`` (a
``postgresql+psycopg://`` URL of a superuser) uses an existing server instead."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

from tests.service.conftest import ROOT, free_port

SETUP = ROOT / "tests" / "postgres" / "setup.sh"
DB_USER = "postgres"


class PostgresUnavailableError(RuntimeError):
    pass


def _run(cmd: list[str], timeout: float = 120) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise PostgresUnavailableError(f"{' '.join(cmd)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}")
    return done


def bin_dir() -> Path:
    """The PostgreSQL server binaries, installed by setup.sh if missing."""
    try:
        done = _run(["sh", str(SETUP)], timeout=900)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise PostgresUnavailableError(f"tests/postgres/setup.sh: {exc}") from exc
    lines = done.stdout.strip().splitlines()
    if not lines or not (Path(lines[-1]) / "initdb").exists():
        raise PostgresUnavailableError(f"tests/postgres/setup.sh found no initdb:\n{done.stdout}\n{done.stderr}")
    return Path(lines[-1])


class Cluster:
    """A throwaway cluster in a temp dir that a test may stop and start again (an outage)."""

    def __init__(self) -> None:
        self.bindir = bin_dir()
        self.as_postgres: list[str] = []
        if os.geteuid() == 0:
            if shutil.which("runuser") is None:
                raise PostgresUnavailableError("running as root but runuser is missing (postgres refuses to run as root)")
            self.as_postgres = ["runuser", "-u", "postgres", "--"]
        # in /tmp: the postgres user must reach it, and unix socket paths are limited to ~100 chars
        self.base = Path(tempfile.mkdtemp(prefix="spacearm-pg-", dir="/tmp" if Path("/tmp").is_dir() else None))
        self.data, self.log = self.base / "data", self.base / "server.log"
        self.port = free_port()
        self.running = False
        initdb = [str(self.bindir / "initdb"), "-D", str(self.data), "-U", DB_USER, "-A", "trust", "-E", "UTF8", "--no-sync"]
        try:
            if self.as_postgres:
                shutil.chown(self.base, "postgres", "postgres")
            self.base.chmod(0o700)
            _run([*self.as_postgres, *initdb])
        except BaseException:
            shutil.rmtree(self.base, ignore_errors=True)
            raise
        #: the superuser's URL of the ``postgres`` database, over the unix socket
        self.admin_url = f"postgresql+psycopg://{DB_USER}@/postgres?host={self.base}&port={self.port}"

    def start(self) -> None:
        options = (
            f"-p {self.port} -k {self.base} -c listen_addresses=127.0.0.1 -c fsync=off -c synchronous_commit=off "
            "-c full_page_writes=off -c max_connections=100"
        )
        ctl = [str(self.bindir / "pg_ctl"), "-D", str(self.data), "-l", str(self.log), "-o", options, "-w", "-t", "60"]
        try:
            _run([*self.as_postgres, *ctl, "start"])
        except PostgresUnavailableError as exc:
            server_log = self.log.read_text() if self.log.exists() else ""
            raise PostgresUnavailableError(f"{exc}\nserver log:\n{server_log}") from None
        self.running = True

    def stop(self) -> None:
        """``pg_ctl stop -m fast``: sessions are ended, new connections refused."""
        subprocess.run(
            [*self.as_postgres, str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", "fast", "-w", "stop"],
            capture_output=True,
            timeout=60,
        )
        self.running = False

    def remove(self) -> None:
        if self.running:
            self.stop()
        shutil.rmtree(self.base, ignore_errors=True)


def create_database(url: str, name: str | None = None) -> str:
    """Create a database (a fresh one per test) on the server of ``url``; return its URL."""
    name = name or f"t_{uuid.uuid4().hex[:12]}"
    engine = create_engine(url, isolation_level="AUTOCOMMIT")
    try:
        with engine.connect() as conn:
            conn.execute(text(f'CREATE DATABASE "{name}"'))
    finally:
        engine.dispose()
    return make_url(url).set(database=name).render_as_string(hide_password=False)


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    """URL of an empty database on a throwaway PostgreSQL cluster (for the whole session)."""
    external = os.environ.get("SPACEARM_TEST_POSTGRES_URL")
    if external:
        yield create_database(external)
        return
    cluster = started_cluster()
    try:
        yield create_database(cluster.admin_url, "spacearm")
    finally:
        cluster.remove()


@pytest.fixture
def pg_url(postgres_url: str) -> str:
    """A fresh database of its own for one test, on the session's cluster."""
    return create_database(postgres_url)


def started_cluster() -> Cluster:
    """A started cluster; if PostgreSQL cannot be installed or started, the test fails when
    ``CI=true`` and is skipped otherwise."""
    cluster = None
    try:
        cluster = Cluster()
        cluster.start()
    except PostgresUnavailableError as exc:
        if cluster is not None:
            cluster.remove()
        message = f"PostgreSQL is not available: {exc}"
        if os.environ.get("CI", "").lower() in ("true", "1"):
            pytest.fail(message)
        pytest.skip(message)
    return cluster


@pytest.fixture
def own_cluster() -> Iterator[Cluster]:
    """A running cluster of this test's own, which it may stop and start (the session's cluster
    serves other tests); never an external server."""
    cluster = started_cluster()
    try:
        yield cluster
    finally:
        cluster.remove()
