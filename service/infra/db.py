"""Engine and sessions, and what a database fault means for a request.

SQLite runs in WAL mode with a busy timeout (set on every connection). At run time the file is
opened read-write *without* being created (``mode=rw``): a database file deleted under a running
service is an error, not a new empty database; the file the service holds is compared with the
file at its path before every session, so writes never go to a deleted or replaced file. Only
``spacearm migrate`` creates the file, and its engine runs DDL inside transactions (pysqlite
would otherwise commit each ``CREATE TABLE`` on its own), so a migration is all or nothing.

Any other database (PostgreSQL: ``postgresql+psycopg://...``) gets a pooled engine that checks
connections before use. Transactions that SQLite refuses for a lock, or that PostgreSQL aborts
for a deadlock or a serialization failure, are retried. Faults that a retry cannot cure right
away (read-only or full storage, a missing file, a lost server, an exhausted connection pool)
are :class:`DatabaseUnavailableError`-like: the API answers 503 with ``Retry-After`` and drops
its pooled connections, so it recovers by itself when the fault ends.
"""

from __future__ import annotations

import contextvars
import functools
import hashlib
import logging
import os
import random
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ParamSpec, TypeVar, cast
from urllib.parse import quote, unquote

from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import QueuePool

from service.infra import jsonio
from service.infra.checkpoint import BACKSTOP_PAGES
from service.infra.loop import HandOff, on_event_loop
from service.infra.reserve import DiskReserve

P = ParamSpec("P")
T = TypeVar("T")

LOCK_RETRIES = 8
CONNECT_TIMEOUT_S = 10
log = logging.getLogger("spacearm.db")


# PostgreSQL SQLSTATEs of transactions worth running again: serialization_failure,
# deadlock_detected, lock_not_available
RETRYABLE_SQLSTATES = frozenset({"40001", "40P01", "55P03"})
# PostgreSQL SQLSTATE classes and codes of an unavailable database: connection exceptions (08),
# read-only transaction, insufficient resources (53: disk full, out of memory, too many
# connections), operator intervention (57: shutdown, cannot connect now)
UNAVAILABLE_SQLSTATES = ("08", "25006", "53", "57")
DISK_FULL = "the database's disk is full"
# SQLite's words for the same (read-only file, full disk, missing or unreadable file, I/O error)
UNAVAILABLE_SQLITE = ("readonly", "read-only", "disk is full", "unable to open", "disk i/o error", "not a database")


class DatabaseUnavailableError(Exception):
    """The database cannot serve this request now (see :func:`unavailable_reason`)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def is_locked(exc: BaseException) -> bool:
    """SQLite's "database is locked" / "database is busy" (the busy timeout ran out), or a
    PostgreSQL transaction aborted by a deadlock or a serialization failure."""
    if not isinstance(exc, DBAPIError):
        return False
    if getattr(exc.orig, "sqlstate", None) in RETRYABLE_SQLSTATES:
        return True
    return isinstance(exc, OperationalError) and any(w in str(exc.orig).lower() for w in ("locked", "busy"))


def is_database_fault(exc: BaseException) -> bool:
    """A fault of the database (worth waiting out), as opposed to an error of the work itself."""
    return is_locked(exc) or unavailable_reason(exc) is not None


def unavailable_reason(exc: BaseException) -> str | None:
    """A short reason when ``exc`` means the database cannot serve requests for now (read-only,
    full, missing, unreachable, out of connections), else None. Never the driver's text."""
    if isinstance(exc, DatabaseUnavailableError):
        return exc.reason
    if isinstance(exc, PoolTimeoutError):
        return "every database connection is in use"
    if not isinstance(exc, DBAPIError):
        return None
    state = getattr(exc.orig, "sqlstate", None) or ""
    if state and any(state.startswith(prefix) for prefix in UNAVAILABLE_SQLSTATES):
        return {"25006": "the database is read-only", "53100": DISK_FULL}.get(state, "the database server is unavailable")
    message = str(exc.orig).lower()
    if "readonly" in message or "read-only" in message:
        return "the database is read-only"
    if "disk is full" in message:
        return DISK_FULL
    if any(w in message for w in UNAVAILABLE_SQLITE):
        return "the database file cannot be opened"
    if exc.connection_invalidated:
        return "the database connection was lost"
    if isinstance(exc, OperationalError) and not state and not isinstance(exc.orig, sqlite3.Error):
        # a database server's driver (psycopg) raises OperationalError without a SQLSTATE only for
        # its side of the connection: refused, no socket, timed out, closed under it. The server's
        # own errors all carry a SQLSTATE, and SQLAlchemy classifies none of these at connect time.
        return "the database server cannot be reached"
    return None


#: Set while work runs on the event loop (:func:`elsewhere_if_locked`): a SQLite session there does
#: not wait for another writer's lock.
_NO_WAIT = contextvars.ContextVar("spacearm_db_no_wait", default=False)


class WouldWaitError(HandOff):
    """Work on the event loop found the database locked by another writer (a retention sweep, a
    migration): ``then`` is the rest of it, to run where waiting blocks nothing (the thread pool)."""

    def __init__(self, then: Callable[[], Any]) -> None:
        super().__init__(then, "the database is locked by another writer")


@contextmanager
def elsewhere_if_locked(then: Callable[[], Any]) -> Iterator[None]:
    """Within, on the event loop's thread: SQLite sessions do not wait for the write lock (the loop
    would stop for up to the busy timeout, ``/healthz`` with it); if it is taken,
    :class:`WouldWaitError` with ``then`` instead (whose own sessions wait as usual). Elsewhere (a
    thread of the pool): nothing changes."""
    if not on_event_loop():
        yield
        return
    token = _NO_WAIT.set(True)
    try:
        yield
    except OperationalError as exc:
        if is_locked(exc):
            raise WouldWaitError(then) from exc
        raise
    finally:
        _NO_WAIT.reset(token)


def retry_locked(fn: Callable[P, T]) -> Callable[P, T]:
    """Run ``fn`` again (in a new transaction: it must open its own session) when SQLite says the
    database is locked or PostgreSQL aborted the transaction (deadlock, serialization failure),
    with jittered exponential backoff; SQLite's busy timeout already waited on every attempt, so
    this only covers lock upgrades that SQLite refuses to wait for."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> T:
        for attempt in range(LOCK_RETRIES):
            try:
                return fn(*args, **kwargs)
            except DBAPIError as exc:
                if not is_locked(exc) or attempt == LOCK_RETRIES - 1:
                    raise
                time.sleep(min(0.02 * 2**attempt, 1.0) * (0.5 + random.random()))
        raise AssertionError("unreachable")

    return wrapper


def sqlite_path(url: str | URL) -> Path | None:
    """The file of a SQLite URL (None for other databases and in-memory SQLite)."""
    parsed = make_url(url)
    if parsed.get_backend_name() != "sqlite" or not parsed.database or parsed.database == ":memory:":
        return None
    database = parsed.database
    if database.startswith("file:"):  # a URI (how make_engine opens an existing file)
        database = unquote(database[len("file:") :].split("?", 1)[0])
    return Path(database).expanduser()


def ensure_sqlite_dir(url: str) -> None:
    path = sqlite_path(url)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)


def _open_existing(url: URL, path: Path) -> URL:
    """The same SQLite database opened as a URI with ``mode=rw``: never created by connecting."""
    return url.set(database=f"file:{quote(str(path.resolve()))}?mode=rw", query={**url.query, "uri": "true"})


def make_engine(
    url: str,
    busy_timeout_ms: int = 10_000,
    *,
    create: bool = False,
    pool_size: int = 5,
    max_overflow: int = 10,
    pool_timeout_s: float = 30.0,
    background_checkpoints: bool = False,
) -> Engine:
    """An engine for ``url``. SQLite: ``create`` lets connecting create the file and makes DDL
    transactional (for migrations); ``busy_timeout_ms`` only applies to SQLite;
    ``background_checkpoints``: commits leave the WAL to a :class:`service.infra.checkpoint.Checkpointer`
    up to :data:`~service.infra.checkpoint.BACKSTOP_PAGES`.
    The pool's size, overflow and timeout apply to every database."""
    ensure_sqlite_dir(url)
    parsed = make_url(url)
    path = sqlite_path(parsed)
    is_sqlite = parsed.get_backend_name() == "sqlite"
    # JSON columns through orjson (see service.infra.jsonio), NaN and infinities as null.
    kwargs: dict[str, Any] = {
        "json_serializer": jsonio.dumps_text,
        "json_deserializer": jsonio.loads,
        "pool_size": pool_size,
        "max_overflow": max_overflow,
        "pool_timeout": pool_timeout_s,
    }
    if is_sqlite:
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": busy_timeout_ms / 1000.0}
        if path is not None and not create:
            parsed = _open_existing(parsed, path)
    else:
        # a server restart or a dropped connection must not fail the next request or heartbeat
        kwargs["pool_pre_ping"] = True
        if parsed.get_backend_name() == "postgresql" and "connect_timeout" not in parsed.query:
            kwargs["connect_args"] = {"connect_timeout": CONNECT_TIMEOUT_S}  # /readyz answers instead of hanging
    if path is None and is_sqlite:  # in-memory: no pool sizes
        for key in ("pool_size", "max_overflow", "pool_timeout"):
            kwargs.pop(key)
    engine = create_engine(parsed, **kwargs)
    if is_sqlite:

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
            if create:
                # pysqlite opens transactions only before DML; let SQLAlchemy begin them (below)
                dbapi_connection.isolation_level = None
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute(f"PRAGMA busy_timeout={int(busy_timeout_ms)}")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA synchronous=NORMAL")
            if background_checkpoints:
                cursor.execute(f"PRAGMA wal_autocheckpoint={BACKSTOP_PAGES}")
            cursor.close()

        if create:

            @event.listens_for(engine, "begin")
            def _begin(conn: Any) -> None:
                conn.exec_driver_sql("BEGIN IMMEDIATE")  # DDL and the version stamp in one transaction

    return engine


class Database:
    """An engine and its session factory. For SQLite it remembers which file it opened (device
    and inode) and checks, before every session, that the path still names that file; it keeps a
    reserve of disk space for deletions (:mod:`service.infra.reserve`)."""

    def __init__(
        self,
        url: str,
        busy_timeout_ms: int = 10_000,
        *,
        pool_size: int = 5,
        max_overflow: int = 10,
        pool_timeout_s: float = 30.0,
        background_checkpoints: bool = False,
    ) -> None:
        self.url = url
        self.path = sqlite_path(url)
        self.busy_timeout_ms = busy_timeout_ms
        self.engine = make_engine(
            url,
            busy_timeout_ms,
            pool_size=pool_size,
            max_overflow=max_overflow,
            pool_timeout_s=pool_timeout_s,
            background_checkpoints=background_checkpoints,
        )
        self.sessionmaker = sessionmaker(self.engine, expire_on_commit=False)
        self._identity: tuple[int, int, bool] | None = None
        self._lock = threading.Lock()
        self.reserve = DiskReserve(self.path)

    def check_file(self) -> None:
        """Raise :class:`DatabaseUnavailableError` if the SQLite file is missing; if the path now
        names another file (restored from a backup, migrated anew), or the file became writable
        or read-only for this process, drop the pooled connections so the next ones open it
        afresh (SQLite opens a file it may not write read-only, and such a connection stays
        read-only after the file is writable again)."""
        if self.path is None:
            return
        try:
            st = os.stat(self.path)
        except OSError:
            raise DatabaseUnavailableError(
                f"the database file {self.path} is missing: restore it, or create it with `spacearm migrate`"
            ) from None
        self.reserve.keep()
        identity = (st.st_dev, st.st_ino, os.access(self.path, os.W_OK))
        with self._lock:
            if self._identity is None:
                self._identity = identity
            elif identity[:2] != self._identity[:2]:
                log.warning("the database file %s was replaced: reconnecting", self.path)
                self._identity = identity
                self.engine.dispose()
            elif identity != self._identity:
                state = "writable" if identity[2] else "read-only"
                log.warning("the database file %s became %s: reconnecting", self.path, state)
                self._identity = identity
                self.engine.dispose()

    def recover(self, exc: BaseException) -> str | None:
        """If ``exc`` means the database is unavailable, drop the pooled connections (a
        connection opened while the file was read-only stays read-only) and return the reason."""
        reason = unavailable_reason(exc)
        if reason is not None and not isinstance(exc, PoolTimeoutError):
            self.engine.dispose()
        return reason

    def spare_connection(self) -> bool:
        """Whether the pool has a connection that nobody holds, so that taking one waits for
        nothing (work on the event loop asks first: start-up's rehearsal, or a handler holding
        two connections, may hold the one the pool keeps for the loop)."""
        pool = self.engine.pool
        if not isinstance(pool, QueuePool):
            return True
        return pool.checkedout() < pool.size()

    @contextmanager
    def session(self) -> Iterator[Session]:
        """An ORM session in a transaction, committed when the block ends (rolled back if it
        raises), after :meth:`check_file`; see :func:`elsewhere_if_locked` for the event loop."""
        self.check_file()
        with self.sessionmaker() as session, self._transaction(session, lambda: session.connection().connection, session.flush):
            yield session

    @contextmanager
    def connection(self) -> Iterator[Connection]:
        """:meth:`session` without the ORM: a Core connection in a transaction, for a lone insert
        (a plan's: 0.09 ms less than through a session, the median of 1,400 alternated inserts)."""
        self.check_file()
        with self.engine.connect() as conn, self._transaction(conn, lambda: conn.connection, lambda: None):
            yield conn

    @contextmanager
    def _transaction(self, unit: Session | Connection, pooled_of: Callable[[], Any], flush: Callable[[], None]) -> Iterator[None]:
        """Commit ``unit`` when the block ends, roll it back if it raises; on the event loop
        (:func:`elsewhere_if_locked`), a SQLite connection waits for no lock meanwhile."""
        no_wait = self.path is not None and _NO_WAIT.get()
        pooled = pooled_of() if no_wait else None
        if pooled is not None:
            cast(sqlite3.Connection, pooled.driver_connection).execute("PRAGMA busy_timeout=0")
        try:
            try:
                yield
                if pooled is not None:
                    flush()  # the ORM's pending writes too, before the timeout is back
            finally:
                # back before the commit or rollback gives the connection back to the pool
                if pooled is not None:
                    self._restore_busy_timeout(pooled)
            unit.commit()
        except BaseException:
            unit.rollback()
            raise

    def _restore_busy_timeout(self, pooled: Any) -> None:
        """Give a pooled SQLite connection the engine's busy timeout again; one that refuses is
        dropped from the pool (it must not go back without it)."""
        try:
            cast(sqlite3.Connection, pooled.driver_connection).execute(f"PRAGMA busy_timeout={int(self.busy_timeout_ms)}")
        except sqlite3.Error:
            pooled.invalidate()

    def write(self, build: Callable[[Session], T], *, exclusive: str | None = None) -> T:
        """Run ``build`` in its own session and commit, retried when the database is locked.
        ``exclusive`` names a lock the transaction holds from its start (:meth:`hold`)."""

        @retry_locked
        def attempt() -> T:
            with self.session() as session:
                if exclusive is not None:
                    self.hold(session, exclusive)
                return build(session)

        return attempt()

    def freeing(self, run: Callable[[], T]) -> T:
        """Run ``run``, a deletion in transactions of its own; if the disk is full, give back the
        reserve and run it once more, then checkpoint the WAL into the database file
        (``TRUNCATE``: the WAL's space is returned too)."""
        try:
            return run()
        except DBAPIError as exc:
            if unavailable_reason(exc) != DISK_FULL or not self.reserve.release():
                raise
        result = run()
        try:
            with self.engine.connect() as conn:
                conn.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
        except DBAPIError as exc:  # readers in the way: the next checkpoint does it
            log.info("checkpoint after a deletion on a full disk: %s", type(exc).__name__)
        return result

    def hold(self, session: Session, name: str) -> None:
        """Take the lock ``name`` for the rest of ``session``'s transaction (first thing in it):
        transactions that hold the same lock run one at a time, so what one reads (a count) stays
        true until it commits. SQLite: ``BEGIN IMMEDIATE`` (the write lock, which serialises every
        writer); PostgreSQL: a transaction-level advisory lock (only these transactions wait)."""
        backend = self.engine.dialect.name
        if backend == "sqlite":
            session.connection().exec_driver_sql("BEGIN IMMEDIATE")
        elif backend == "postgresql":
            key = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "big", signed=True)
            session.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": key})
        else:  # pragma: no cover - only SQLite and PostgreSQL are supported
            raise NotImplementedError(f"no exclusive transactions on {backend}")

    def dispose(self) -> None:
        self.engine.dispose()
