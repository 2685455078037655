"""Admission control for expensive synchronous work (plans, landscapes, uploads, figure renders),
by estimated work rather than by count.

Each request states its cost (a plan: its joint-steps, :func:`plan_cost`; other work a default),
and the admission keeps the backlog: the estimated seconds of the work admitted and not finished.
A request is admitted when the backlog ahead of it would drain through the ``slots`` within
``wait_s``; otherwise it is refused at once with a 503 whose ``Retry-After`` is the time until
the backlog has drained that far. The seconds per unit of cost are measured as requests finish
(a moving average), so the estimate follows the machine and its load. ``queue`` caps the
requests waiting at once whatever their cost (memory; ``0``: no waiting at all), and twice
``wait_s`` is a backstop on each wait (the work ahead may run slower than measured: requests
running side by side share the cores). Waiting happens on the event loop, so a queued request holds
neither a thread nor a database connection, and ``/healthz`` is answered throughout."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import AsyncIterator, Mapping
from contextlib import asynccontextmanager
from typing import Any

from service.errors import ApiError

#: A request's fixed cost in joint-steps (parsing, storing, answering: a few milliseconds).
REQUEST_OVERHEAD = 4000.0
#: The cost of work that states none (an upload, a figure), in joint-steps.
DEFAULT_COST = 20_000.0
#: Seconds per joint-step before anything was measured (one core, with the request's overhead).
INITIAL_SECONDS_PER_COST = 1.5e-6
#: Weight of the newest measurement in the moving average.
SMOOTHING = 0.1
#: An admitted request waits at most this many times the timeout (its estimate was too low: the
#: work ahead ran slower than measured), then gets a 503.
BACKSTOP = 2.0
#: Work of at most this many joint-steps runs on the event loop, not in the thread pool: a paper
#: plan (4,366 joint-steps, 4,732 replayed) up to a 6-joint plan of 500 steps, a few milliseconds
#: each. Handing such work to a thread and back cost a paper plan's request 0.6-1.3 ms of CPU of its
#: 3-4 ms (measured over HTTP). The loop is blocked that long, so ``/healthz`` and the other
#: requests wait at most a few milliseconds per such plan; larger work keeps the thread pool.
INLINE_MAX_COST = REQUEST_OVERHEAD + 3_000.0
#: A stored plan whose request and trajectory take at most this many bytes is read, validated and
#: encoded on the event loop where cheap plans run (``GET /v1/plans/{id}``): a paper plan's 29 kB
#: took 0.9 ms, so this is about 2 ms. A larger one is read in the thread pool (a 20,000-step
#: plan's JSON takes 60 ms; an inline robot of many shapes makes a large request to validate).
INLINE_READ_BYTES = 64 * 1024


class OverloadedError(ApiError):
    def __init__(self, what: str, retry_after_s: int, why: str = "") -> None:
        super().__init__(
            503,
            f"too many {what} in progress{why}; retry after {retry_after_s} s",
            type_="https://spacearm.example/problems/overloaded",
            title="Service Unavailable",
            headers={"Retry-After": str(retry_after_s)},
        )


def work_cost(samples: float, joints: float, runs: float) -> float:
    """Joint-steps of ``runs`` passes over ``samples`` samples of ``joints`` joints, with the
    request's fixed :data:`REQUEST_OVERHEAD`."""
    return REQUEST_OVERHEAD + runs * samples * joints


def plan_cost(body: Mapping[str, Any]) -> float:
    """A plan request's cost in joint-steps, from its JSON body before it is validated: the task's
    steps (duration over ``dt_s``) times the robot's joints (an inline robot's links, else 6), twice
    when replayed, plus two loops per sample under uncertainty, plus :data:`REQUEST_OVERHEAD`. A body
    it cannot read costs a paper plan (it is refused by validation anyway). A stored plan planned
    again (``from_plan_id``) has the task of a plan not read yet: :data:`DEFAULT_COST`."""
    if "from_plan_id" in body:
        return DEFAULT_COST
    try:
        task = body.get("task") or {}
        duration = float(task.get("duration_s") or 15.0)
        dt = float(task.get("dt_s") or 0.25)
        steps = min(math.ceil(duration / dt), 10_000_000) + 1 if dt > 0.0 and math.isfinite(duration / dt) else 61
        robot = body.get("robot")
        joints = len(robot.get("links") or []) or 6 if isinstance(robot, Mapping) else 6
        uncertainty = body.get("uncertainty")
        samples = int(uncertainty.get("samples", 64)) if isinstance(uncertainty, Mapping) else 0
        runs = (2.0 if body.get("replay", True) else 1.0) + 2.0 * max(0, min(samples, 1024))
    except (AttributeError, TypeError, ValueError, OverflowError):
        return work_cost(61, 6, 1.0)
    return work_cost(steps, joints, runs)


class Admission:
    """Slots, a backlog of estimated work, and a cap on waiting requests; ``what`` names the work
    in messages; work of at most ``inline_max_cost`` runs on the event loop (0: none)."""

    def __init__(self, what: str, slots: int, queue: int, wait_s: float, inline_max_cost: float = 0.0) -> None:
        self.what = what
        self.inline_max_cost = inline_max_cost  # work up to this cost runs on the event loop (INLINE_MAX_COST)
        self.slots = slots
        self.queue = queue
        self.wait_s = wait_s
        self.running = 0
        self.waiting = 0
        self.refused = 0
        self.backlog_s = 0.0  # estimated seconds of the admitted work not finished (running and waiting)
        self.seconds_per_cost = INITIAL_SECONDS_PER_COST
        self._semaphore: asyncio.Semaphore | None = None
        self._loop_turns: dict[str, asyncio.Lock] = {}

    def estimated_wait_s(self) -> float:
        """How long a request admitted now would wait for a slot: the backlog over the slots."""
        return self.backlog_s / self.slots if self.running >= self.slots else 0.0

    def _refuse(self, what: str, retry_after_s: float, why: str = "") -> OverloadedError:
        self.refused += 1
        return OverloadedError(what, max(1, math.ceil(min(retry_after_s, 3600.0))), why)

    @asynccontextmanager
    async def slot(self, what: str | None = None, cost: float = DEFAULT_COST) -> AsyncIterator[None]:
        """Hold one of the slots for work of ``cost`` joint-steps (``what`` names it in a 503)."""
        if self._semaphore is None:  # created on the event loop that uses it
            self._semaphore = asyncio.Semaphore(self.slots)
        name = what or self.what
        wait = self.estimated_wait_s()
        if self.running >= self.slots and self.waiting >= self.queue:
            raise self._refuse(name, max(wait, 1.0))
        if wait > self.wait_s:
            raise self._refuse(name, wait - self.wait_s, f" (about {wait:.1f} s of work ahead)")
        estimate = cost * self.seconds_per_cost
        self.backlog_s += estimate
        self.waiting += 1
        try:
            if self._semaphore.locked():  # the backstop: twice the timeout, for estimates that were low
                await asyncio.wait_for(self._semaphore.acquire(), BACKSTOP * self.wait_s)
            else:  # a free slot: taken at once
                await self._semaphore.acquire()
        except TimeoutError:
            self.backlog_s -= estimate
            waited = f" (waited {BACKSTOP * self.wait_s:g} s: the work ahead ran slower than estimated)"
            raise self._refuse(name, self.estimated_wait_s(), waited) from None
        finally:
            self.waiting -= 1
        self.running += 1
        started = time.perf_counter()
        try:
            yield
        finally:
            self.running -= 1
            self.backlog_s = max(0.0, self.backlog_s - estimate)
            measured = (time.perf_counter() - started) / max(cost, 1.0)
            self.seconds_per_cost += SMOOTHING * (measured - self.seconds_per_cost)
            self._semaphore.release()

    @asynccontextmanager
    async def loop_turn(self, kind: str = "plans") -> AsyncIterator[None]:
        """A turn for work of ``kind`` that runs on the event loop (cheap plans,
        :data:`INLINE_MAX_COST`; small reads, :data:`INLINE_READ_BYTES`): one of a kind at a time,
        and the next not before the loop's next pass over its sockets. Requests that arrive together
        reach their work in one pass of the loop; run back to back there, a burst of 100 paper plans
        kept ``/healthz`` waiting for all of them (a second). Each kind has its turns (reads are not
        admitted: queued among the plans' turns, they would slow the plans the admission
        measures)."""
        turn = self._loop_turns.get(kind)
        if turn is None:  # created on the event loop that uses it
            turn = self._loop_turns[kind] = asyncio.Lock()
        await turn.acquire()
        try:
            yield
        finally:
            # released by a callback of the loop's next pass, which begins by polling the sockets
            asyncio.get_running_loop().call_soon(turn.release)
