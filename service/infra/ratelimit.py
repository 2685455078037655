"""Per-address rate limits, in this process's memory (the ``limits`` library's moving window, the
engine behind Flask-Limiter and SlowAPI): ``POST /login`` takes at most
``SPACEARM_LOGIN_ATTEMPTS_PER_MINUTE`` attempts per client address per minute, right or wrong,
so keys cannot be guessed at speed. Each API process counts on its own; behind a proxy, the
client address is the one uvicorn takes from ``X-Forwarded-For`` of a trusted proxy
(``FORWARDED_ALLOW_IPS``, 127.0.0.1 by default)."""

from __future__ import annotations

import math
import time

from limits import RateLimitItemPerMinute
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter


class AddressLimiter:
    """At most ``per_minute`` hits per address in any minute."""

    def __init__(self, name: str, per_minute: int) -> None:
        self.name = name
        self.item = RateLimitItemPerMinute(per_minute)
        self.limiter = MovingWindowRateLimiter(MemoryStorage())

    def hit(self, address: str) -> int | None:
        """Count an attempt from ``address``: None if it is allowed, else the seconds until the
        next one is (for ``Retry-After``)."""
        if self.limiter.hit(self.item, self.name, address):
            return None
        reset = self.limiter.get_window_stats(self.item, self.name, address).reset_time
        return max(1, math.ceil(reset - time.time()))
