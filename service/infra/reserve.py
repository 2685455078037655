"""Room to delete on a full disk (SQLite).

A SQLite deletion writes too (the changed pages go to the WAL first), so on a full disk a DELETE
would fail like any write and space could not be freed through the API. Every process keeps a
reserve file of :data:`RESERVE_BYTES` beside the database (``<database>-reserve``), created when
missing and there is room for it; a deletion that fails for a full disk gives it back and runs
again (:meth:`service.infra.db.Database.freeing`), after which a ``TRUNCATE`` checkpoint moves the
WAL into the database file (whose freed pages new rows reuse) and returns the WAL's space."""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from pathlib import Path

log = logging.getLogger("spacearm.db")

RESERVE_BYTES = 1 << 20
#: How often a missing reserve is made again (when the disk has room).
CHECK_EVERY_S = 30.0


class DiskReserve:
    """The reserve file of the SQLite database at ``database`` (none for other databases)."""

    def __init__(self, database: Path | None) -> None:
        self.path = database.with_name(database.name + "-reserve") if database is not None else None
        self._checked = -float("inf")
        self._lock = threading.Lock()

    def keep(self) -> None:
        """Make the reserve if it is missing and the disk has room for it (looked at every
        :data:`CHECK_EVERY_S` at most)."""
        if self.path is None:
            return
        with self._lock:
            now = time.monotonic()
            if now - self._checked < CHECK_EVERY_S:
                return
            self._checked = now
        if self.path.exists() or not self.path.parent.is_dir():
            return
        partial = self.path.with_name(f"{self.path.name}.{os.getpid()}.{threading.get_ident()}")
        try:
            fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            try:
                try:
                    os.posix_fallocate(fd, 0, RESERVE_BYTES)
                except OSError as exc:
                    if exc.errno not in (95, 22):  # EOPNOTSUPP, EINVAL: a file system without fallocate
                        raise
                    os.write(fd, b"\0" * RESERVE_BYTES)
            finally:
                os.close(fd)
            os.replace(partial, self.path)
        except OSError:  # no room (or not writable): tried again later
            with contextlib.suppress(OSError):
                partial.unlink()

    def release(self) -> bool:
        """Give the reserve's space back; whether there was a reserve."""
        if self.path is None:
            return False
        try:
            self.path.unlink()
        except OSError:
            return False
        self._checked = time.monotonic()  # not made again at once: the deletion needs the room
        log.warning("the database's disk is full: gave back the %d-byte reserve so that a deletion can run", RESERVE_BYTES)
        return True
