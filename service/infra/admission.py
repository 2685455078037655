"""Admission control for expensive synchronous work (plans, figure renders): at most ``slots``
requests run at once, at most ``queue`` more wait (each for at most ``wait_s``); beyond that a
request is refused at once with a 503 and ``Retry-After``, instead of piling up in the thread
pool, exhausting the database pool and timing out. Waiting happens on the event loop, so a
queued request holds neither a thread nor a database connection."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from service.errors import ApiError


class OverloadedError(ApiError):
    def __init__(self, what: str, retry_after_s: int) -> None:
        super().__init__(
            503,
            f"too many {what} in progress; retry after {retry_after_s} s",
            type_="https://spacearm.example/problems/overloaded",
            title="Service Unavailable",
            headers={"Retry-After": str(retry_after_s)},
        )


class Admission:
    """A bounded semaphore with a bounded, timed queue; ``what`` names the work in messages."""

    def __init__(self, what: str, slots: int, queue: int, wait_s: float) -> None:
        self.what = what
        self.slots = slots
        self.queue = queue
        self.wait_s = wait_s
        self.running = 0
        self.waiting = 0
        self.refused = 0
        self._semaphore: asyncio.Semaphore | None = None

    def _retry_after(self) -> int:
        return max(1, math.ceil(min(self.wait_s, 30.0)))

    @asynccontextmanager
    async def slot(self, what: str | None = None) -> AsyncIterator[None]:
        """Hold one of the slots (``what`` names the work in a 503, ``self.what`` by default)."""
        if self._semaphore is None:  # created on the event loop that uses it
            self._semaphore = asyncio.Semaphore(self.slots)
        if self.running >= self.slots and self.waiting >= self.queue:
            self.refused += 1
            raise OverloadedError(what or self.what, self._retry_after())
        self.waiting += 1
        try:
            await asyncio.wait_for(self._semaphore.acquire(), self.wait_s)
        except TimeoutError:
            self.refused += 1
            raise OverloadedError(what or self.what, self._retry_after()) from None
        finally:
            self.waiting -= 1
        self.running += 1
        try:
            yield
        finally:
            self.running -= 1
            self._semaphore.release()
