"""Per-address rate limits, in this process's memory (the ``limits`` library's moving window, the
engine behind Flask-Limiter and SlowAPI): ``POST /login`` takes at most
``SPACEARM_LOGIN_ATTEMPTS_PER_MINUTE`` attempts per client address per minute, right or wrong,
so keys cannot be guessed at speed. Each API process counts on its own; behind a proxy, the
client address is the one uvicorn takes from ``X-Forwarded-For`` of a trusted proxy
(``FORWARDED_ALLOW_IPS``, 127.0.0.1 by default)."""

from __future__ import annotations

import math
import time
from typing import Any


class AddressLimiter:
    """At most ``per_minute`` hits per address in any minute."""

    def __init__(self, name: str, per_minute: int) -> None:
        self.name = name
        self.per_minute = per_minute
        self._limiter: Any = None

    def _ready(self) -> Any:
        """The limiter, made on the first hit (``limits`` takes 0.15 s to import: not at start-up)."""
        if self._limiter is None:
            from limits import RateLimitItemPerMinute
            from limits.storage import MemoryStorage
            from limits.strategies import MovingWindowRateLimiter

            self.item = RateLimitItemPerMinute(self.per_minute)
            self._limiter = MovingWindowRateLimiter(MemoryStorage())
        return self._limiter

    def hit(self, address: str) -> int | None:
        """Count an attempt from ``address``: None if it is allowed, else the seconds until the
        next one is (for ``Retry-After``)."""
        limiter = self._ready()
        if limiter.hit(self.item, self.name, address):
            return None
        reset = limiter.get_window_stats(self.item, self.name, address).reset_time
        return max(1, math.ceil(reset - time.time()))
