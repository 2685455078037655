"""Event-loop benchmark for large response bodies: how late an asyncio loop's 5 ms timer fires
while 8 worker threads each build the JSON body of a 20,000-step plan 3 times (as 8 parallel
GETs of a stored plan do), with one orjson call per body (`jsonio.dumps`) and with the body made
in pieces by one thread at a time (`jsonio.dumps_large`, what the plan routes use); prints the
loop's lag (median, p99, max), the timer's turns and the ratios of the p99 and max lags, measured
in one run.

Run: `.venv/bin/python bench/bench_event_loop.py`.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from engine import make_inverse, paper_task, plan, table1_robot
from service.infra import jsonio
from service.schemas.plans import Trajectory
from service.usecases.plans import record_of

THREADS, BODIES_PER_THREAD, TICK_S = 8, 3, 0.005


def plan_body() -> dict[str, Any]:
    """The body of a 20,000-step plan: the paper's line stretched to 500 s, dt 0.025 s."""
    robot = table1_robot()
    paper = paper_task(robot)
    task = dataclasses.replace(paper, path=dataclasses.replace(paper.path, duration=500.0, ramp_time=50.0), dt=0.025)
    result = plan(robot, task, make_inverse("adaptive", lambda_max=0.0571, epsilon=0.0677))
    return {
        "id": "bench",
        "success": result.success,
        "message": result.message,
        "trajectory": Trajectory.arrays(record_of(result, robot)),
    }


async def lags_while(work: Callable[[], object]) -> tuple[np.ndarray, float]:
    """The lags [s] of a ``TICK_S`` timer while ``THREADS`` threads run ``work`` (from before
    the threads start: a loop that cannot even start them counts), and the seconds taken."""
    loop = asyncio.get_running_loop()
    lags: list[float] = []
    start = last = time.perf_counter()
    with ThreadPoolExecutor(THREADS) as pool:
        done = asyncio.gather(*(loop.run_in_executor(pool, work) for _ in range(THREADS)))
        while not done.done():
            await asyncio.sleep(TICK_S)
            now = time.perf_counter()
            lags.append(now - last - TICK_S)
            last = now
        await done
    return np.array(lags), time.perf_counter() - start


def main() -> None:
    body = plan_body()
    size = len(jsonio.dumps(body))
    assert jsonio.dumps_large(body) == jsonio.dumps(body)
    print(f"{THREADS} threads x {BODIES_PER_THREAD} bodies of {size / 2**20:.1f} MiB; a {TICK_S * 1e3:g} ms timer on the loop")
    worst: dict[str, tuple[float, float]] = {}
    for encode in (jsonio.dumps, jsonio.dumps_large):

        def work(encode: Callable[[Any], bytes] = encode) -> None:
            for _ in range(BODIES_PER_THREAD):
                encode(body)

        lags, took = asyncio.run(lags_while(work))
        ms = lags * 1e3
        worst[encode.__name__] = (float(np.percentile(ms, 99)), float(ms.max()))
        print(
            f"{encode.__name__:<12} {took:5.2f} s, {len(ms):4d} timer turns, lag ms: median {np.median(ms):6.1f}, "
            f"p99 {np.percentile(ms, 99):6.1f}, max {ms.max():6.1f}"
        )
    for i, stat in enumerate(("p99", "max")):
        ratio = worst["dumps"][i] / worst["dumps_large"][i] if worst["dumps_large"][i] > 0 else math.inf
        print(f"{stat} lag ratio, one call per body / in pieces: {ratio:.1f}")


if __name__ == "__main__":
    main()
