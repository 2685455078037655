"""When a tuning run ends: after its generations, when cancelled, or at a deadline. One object,
read by the driver between generations and by the planner inside one (it has ``is_set``, the
planner's :class:`engine.planner.Stop`)."""

from __future__ import annotations

import threading
import time


class Termination:
    """Ends a run after ``generations`` generations (after the initial population), when
    :meth:`cancel` is called (from any thread), or ``deadline_s`` seconds after it was made.
    Inside a generation the planner skips the plans not yet started once it is set, so a
    cancellation takes effect within a twentieth of a second or so of work."""

    def __init__(self, generations: int, *, deadline_s: float | None = None) -> None:
        self.generations = generations
        self._deadline = None if deadline_s is None else time.monotonic() + deadline_s
        self._cancelled = threading.Event()
        self._reason: str | None = None

    def cancel(self, reason: str = "cancelled") -> None:
        """Stop the run (the first reason given is kept)."""
        if self._reason is None:
            self._reason = reason
        self._cancelled.set()

    def is_set(self) -> bool:
        """Whether the run must stop now: cancelled, or past its deadline."""
        if self._cancelled.is_set():
            return True
        if self._deadline is not None and time.monotonic() >= self._deadline:
            self.cancel("deadline")
            return True
        return False

    def finished(self, generation: int) -> bool:
        """Whether no generation follows ``generation`` (0: the initial population)."""
        return generation >= self.generations or self.is_set()

    @property
    def reason(self) -> str | None:
        """Why the run was stopped early (``cancelled``, ``deadline``, or the reason given), if it was."""
        return self._reason
