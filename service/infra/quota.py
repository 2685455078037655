"""The storage quota: new robots, meshes, plans, landscapes and jobs are refused with 507 once the database holds
``SPACEARM_STORAGE_QUOTA_BYTES`` (SQLite: the pages in use, so deleted data frees room; PostgreSQL:
``pg_database_size``)."""

from __future__ import annotations

import contextlib
import math
import os
import weakref

from sqlalchemy import Connection, Engine, text
from sqlalchemy.orm import Session

from service.errors import ApiError
from service.infra.db import sqlite_path

MIB = 2**20


class QuotaExceededError(ApiError):
    def __init__(self, used: int, incoming: int, quota: int) -> None:
        super().__init__(
            507,
            f"the storage quota of {quota / MIB:.1f} MiB would be exceeded ({used / MIB:.1f} MiB in use, "
            f"{incoming / MIB:.2f} MiB more): delete plans or jobs you no longer need, or raise "
            "SPACEARM_STORAGE_QUOTA_BYTES",
            used_bytes=used,
            quota_bytes=quota,
        )


#: SQLite's pages in use times their size, in one statement (three PRAGMAs cost a plan 0.08 ms).
SQLITE_BYTES = text(
    "SELECT (p.page_count - f.freelist_count) * s.page_size "
    "FROM pragma_page_count() AS p, pragma_freelist_count() AS f, pragma_page_size() AS s"
)
POSTGRES_BYTES = text("SELECT pg_database_size(current_database())")


def _bind(session: Session | Connection) -> Engine | Connection:
    return session if isinstance(session, Connection) else session.get_bind()


def database_bytes(session: Session | Connection) -> int:
    """Bytes the database holds."""
    sqlite = _bind(session).dialect.name == "sqlite"
    return int(session.execute(SQLITE_BYTES if sqlite else POSTGRES_BYTES).scalar() or 0)


#: The file of each SQLite engine's database (None: not SQLite, or in memory), kept by engine: an
#: engine's URL does not change, and hashing a URL renders it (0.02 ms a plan).
_FILES: weakref.WeakKeyDictionary[Engine, str | None] = weakref.WeakKeyDictionary()


def _file_of(engine: Engine) -> str | None:
    """The file of a SQLite database's ``engine`` (None: not SQLite, or in memory)."""
    try:
        return _FILES[engine]
    except KeyError:
        path = sqlite_path(engine.url)
        found = _FILES[engine] = None if path is None or "mode=memory" in str(engine.url) else str(path)
        return found


def files_bytes(session: Session | Connection) -> float:
    """What a SQLite database's file and its write-ahead log hold, at least the bytes it uses (its
    pages are in the file or, not yet checkpointed, in the log); infinite for other databases, or
    when the file cannot be found (the pages are counted then)."""
    path = _file_of(_bind(session).engine)
    if path is None:
        return math.inf
    try:
        size = os.stat(path).st_size
    except OSError:
        return math.inf
    with contextlib.suppress(OSError):  # no log (yet): the file holds every page
        size += os.stat(f"{path}-wal").st_size
    return float(size)


def check_quota(session: Session | Connection, quota: int | None, incoming: int) -> None:
    """Raise :class:`QuotaExceededError` if storing ``incoming`` more bytes would exceed ``quota``.
    The pages are only counted when the files come near the quota (a query costs a plan 0.2 ms)."""
    if quota is None or files_bytes(session) + incoming <= quota:
        return
    used = database_bytes(session)
    if used + incoming > quota:
        raise QuotaExceededError(used, incoming, quota)
