"""WAL checkpoints of the API's SQLite database off the request path.

In WAL mode a commit appends its pages to the ``-wal`` file, and SQLite copies them into the
database file (a checkpoint, with an ``fsync`` of both files) in the commit that takes the log past
1,000 pages: about one plan commit in a hundred (a paper plan writes 9 pages) then took 7 to 11 ms
instead of 0.04, on the event loop where cheap plans run. Measured with `sqlite3` alone on this
machine's ext4 (3,000 commits of a 28 kB row): a median commit of 42 µs, a mean of 134 µs, a p99 of
7.4 ms.

So a :class:`Checkpointer` thread checkpoints, on a connection of its own, whenever the log has
changed since it last looked (every ``interval_s``): a ``PASSIVE`` checkpoint, which waits for no
lock and blocks no writer (SQLite releases the GIL meanwhile). The API's connections checkpoint
only past :data:`BACKSTOP_PAGES` (``PRAGMA wal_autocheckpoint``, :func:`service.infra.db.make_engine`),
which a steady stream of commits reaches: SQLite starts the log over only when a write begins with
every frame copied, which a checkpoint running beside the commits never leaves (without the
backstop the log grew by 30 MB a second at 700 commits a second). A commit past it copies what the
thread has not, little. Measured with `sqlite3` alone, 6 s of 28 kB commits at 650 a second:

| checkpoints | commit median / mean / p99 | largest log |
|---|---|---|
| SQLite's (1,000 pages) | 87 / 198 / 7,940 µs | 4.2 MB |
| the thread, backstop 1,000 pages | 77 / 152 / 3,609 µs | 4.2 MB |
| the thread, backstop 4,000 pages | 77 / 117 / 164 µs | 16.6 MB |
| the thread alone | 104 / 122 / 267 µs | 184 MB, growing |

The workers, whose commits are few, keep SQLite's own checkpoints; several API processes each run a
thread (two checkpoints at once: one of them finds the other's lock and is skipped).
"""

from __future__ import annotations

import logging
import os
import sqlite3
import threading
from pathlib import Path
from urllib.parse import quote

log = logging.getLogger("spacearm.checkpoint")

#: The API's connections checkpoint themselves past this many pages of log (16 MB).
BACKSTOP_PAGES = 4000
#: How often the thread looks at the log (s): a paper plan a millisecond writes 9 pages a
#: millisecond, so the log stays under about 9 MB between checkpoints.
INTERVAL_S = 0.25


def checkpoint(path: Path) -> tuple[int, int, int]:
    """A ``PASSIVE`` checkpoint of the SQLite database at ``path`` on a connection of its own
    (opened ``mode=rw``: never creates the file); SQLite's ``(busy, log frames, frames
    checkpointed)``."""
    # a second for a lock of the moment (the log starting over); the checkpoint itself waits for none
    conn = sqlite3.connect(f"file:{quote(str(path))}?mode=rw", uri=True, timeout=1.0, check_same_thread=False)
    try:
        row = conn.execute("PRAGMA wal_checkpoint(PASSIVE)").fetchone()
    finally:
        conn.close()
    return int(row[0]), int(row[1]), int(row[2])


class Checkpointer(threading.Thread):
    """Checkpoints the database at ``path`` whenever its log changed (size or time), looked at
    every ``interval_s``, until :meth:`stop`."""

    def __init__(self, path: Path, interval_s: float = INTERVAL_S) -> None:
        super().__init__(name="wal-checkpoint", daemon=True)
        self.path, self.interval_s = path, interval_s
        self.wal = path.with_name(path.name + "-wal")
        self._stop_event = threading.Event()
        self._seen: tuple[int, int] | None = None
        self._failing: str | None = None

    def _log_state(self) -> tuple[int, int] | None:
        try:
            st = os.stat(self.wal)
        except OSError:  # no log yet, or the database is gone (check_file says so to requests)
            return None
        return st.st_size, st.st_mtime_ns

    def step(self) -> bool:
        """Checkpoint if the log changed since the last complete checkpoint; whether it did."""
        state = self._log_state()  # before: a commit during the checkpoint changes it again
        if state is None or state == self._seen:
            return False
        try:
            busy, frames, copied = checkpoint(self.path)
        except sqlite3.Error as exc:  # a missing or read-only file, a full disk: the next look tries again
            if self._failing != str(exc):
                log.warning("WAL checkpoint of %s failed: %s", self.path, exc)
                self._failing = str(exc)
            return False
        self._failing = None
        # busy (another process checkpointing) or incomplete (a reader holds older pages): again next time
        if not busy and copied >= frames:
            self._seen = state
        return not busy

    def run(self) -> None:
        while not self._stop_event.wait(self.interval_s):
            self.step()

    def stop(self) -> None:
        """Stop, after one last checkpoint of what the API committed."""
        self._stop_event.set()
        self.join(timeout=5)
        self.step()
