"""Engine and sessions. SQLite runs in WAL mode with a busy timeout (set on every connection);
any other database (PostgreSQL: ``postgresql+psycopg://...``) gets a pooled engine that checks
connections before use, and transactions that PostgreSQL aborts because of a deadlock or a
serialization failure are retried like SQLite's "database is locked"."""

from __future__ import annotations

import functools
import random
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import make_url
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

from service import jsonio

P = ParamSpec("P")
T = TypeVar("T")

LOCK_RETRIES = 8
CONNECT_TIMEOUT_S = 10


# PostgreSQL SQLSTATEs of transactions worth running again: serialization_failure,
# deadlock_detected, lock_not_available
RETRYABLE_SQLSTATES = frozenset({"40001", "40P01", "55P03"})


def is_locked(exc: BaseException) -> bool:
    """SQLite's "database is locked" / "database is busy" (the busy timeout ran out), or a
    PostgreSQL transaction aborted by a deadlock or a serialization failure."""
    if not isinstance(exc, DBAPIError):
        return False
    if getattr(exc.orig, "sqlstate", None) in RETRYABLE_SQLSTATES:
        return True
    return isinstance(exc, OperationalError) and any(w in str(exc.orig).lower() for w in ("locked", "busy"))


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


def ensure_sqlite_dir(url: str) -> None:
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite" and parsed.database and parsed.database != ":memory:":
        Path(parsed.database).expanduser().parent.mkdir(parents=True, exist_ok=True)


def make_engine(url: str, busy_timeout_ms: int = 10_000) -> Engine:
    """An engine for ``url``. ``busy_timeout_ms`` only applies to SQLite."""
    ensure_sqlite_dir(url)
    parsed = make_url(url)
    is_sqlite = parsed.get_backend_name() == "sqlite"
    # JSON columns through orjson: trajectories are stored straight from the planner's numpy
    # arrays (no Python-list copy), NaN and infinities as null.
    kwargs: dict[str, Any] = {"json_serializer": jsonio.dumps_text, "json_deserializer": jsonio.loads}
    if is_sqlite:
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": busy_timeout_ms / 1000.0}
    else:
        # a server restart or a dropped connection must not fail the next request or heartbeat
        kwargs["pool_pre_ping"] = True
        if parsed.get_backend_name() == "postgresql" and "connect_timeout" not in parsed.query:
            kwargs["connect_args"] = {"connect_timeout": CONNECT_TIMEOUT_S}  # /readyz answers instead of hanging
    engine = create_engine(url, **kwargs)
    if is_sqlite:

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute("PRAGMA journal_mode=WAL")
            cursor.execute(f"PRAGMA busy_timeout={int(busy_timeout_ms)}")
            cursor.execute("PRAGMA foreign_keys=ON")
            cursor.execute("PRAGMA synchronous=NORMAL")
            cursor.close()

    return engine


class Database:
    """An engine and its session factory."""

    def __init__(self, url: str, busy_timeout_ms: int = 10_000) -> None:
        self.url = url
        self.engine = make_engine(url, busy_timeout_ms)
        self.sessionmaker = sessionmaker(self.engine, expire_on_commit=False)

    @contextmanager
    def session(self) -> Iterator[Session]:
        with self.sessionmaker() as session:
            try:
                yield session
                session.commit()
            except BaseException:
                session.rollback()
                raise

    def write(self, build: Callable[[Session], T]) -> T:
        """Run ``build`` in its own session and commit, retried when the database is locked."""

        @retry_locked
        def attempt() -> T:
            with self.session() as session:
                return build(session)

        return attempt()

    def dispose(self) -> None:
        self.engine.dispose()
