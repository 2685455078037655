"""Work that runs on the event loop (cheap plans, :data:`service.infra.admission.INLINE_MAX_COST`;
small reads, :data:`service.infra.admission.INLINE_READ_BYTES`) and hands the rest of itself to
the thread pool when going on would stop the loop: a task larger than its request said, a stored
plan larger than the loop takes, a database locked by another writer."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any


def on_event_loop() -> bool:
    """Whether this thread is running an event loop (a thread of the pool is not)."""
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return False
    return True


class HandOff(Exception):  # noqa: N818 (an instruction, not a failure)
    """Work on the event loop stops here: ``then`` is the rest of it, to run in the thread pool
    (:func:`service.deps.run_admitted`, :func:`service.deps.run_read`)."""

    def __init__(self, then: Callable[[], Any], why: str = "the rest of the work goes to a thread") -> None:
        super().__init__(why)
        self.then = then
