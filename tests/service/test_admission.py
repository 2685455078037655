"""Admission by cost (issue 21): a plan request is admitted when the work admitted before it, in
joint-steps at the measured speed, would drain within the timeout; otherwise a 503 with an
honest Retry-After. The admission alone (its estimate, its refusals) and over HTTP: a burst of
100 paper plans is served in full, a burst of 20,000-step plans as far as the timeout allows,
while /healthz answers."""

from __future__ import annotations

import asyncio
import statistics
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import pytest

from service.infra.admission import REQUEST_OVERHEAD, Admission, OverloadedError, plan_cost
from tests.service.conftest import PAPER_TASK, Stack

TUNED = {"name": "adaptive", "params": {"lambda_max": 0.04, "epsilon": 0.37}}


def test_a_plans_cost_is_its_joint_steps() -> None:
    paper = {"robot_id": "table1", "task": PAPER_TASK, "method": TUNED}
    assert plan_cost(paper) == REQUEST_OVERHEAD + 2 * 61 * 6  # planned and replayed
    assert plan_cost({**paper, "replay": False}) == REQUEST_OVERHEAD + 61 * 6
    robust = {**paper, "replay": False, "uncertainty": {"samples": 10}}
    assert plan_cost(robust) == REQUEST_OVERHEAD + 21 * 61 * 6  # the plan and two loops per sample
    long_task = {**paper, "replay": False, "task": {**PAPER_TASK, "dt_s": 15.0 / 20000}}
    assert plan_cost(long_task) == REQUEST_OVERHEAD + 20001 * 6
    inline = {**paper, "replay": False, "robot": {"links": [{}] * 7}}
    assert plan_cost(inline) == REQUEST_OVERHEAD + 61 * 7
    assert plan_cost({"task": {"dt_s": "x"}}) == REQUEST_OVERHEAD + 61 * 6  # unreadable: validation refuses it


def test_the_admission_refuses_by_estimated_wait_with_an_honest_retry_after() -> None:
    async def scenario() -> None:
        admission = Admission("plans", slots=1, queue=1000, wait_s=2.0)
        admission.seconds_per_cost = 1e-3  # a measured speed: a cost of 1000 is a second
        release = asyncio.Event()

        async def hold(cost: float) -> None:
            async with admission.slot(cost=cost):
                await release.wait()

        first = asyncio.create_task(hold(1000.0))  # runs: a second of work
        await asyncio.sleep(0.05)
        second = asyncio.create_task(hold(500.0))  # waits behind it: 1.5 s of work in all
        await asyncio.sleep(0.05)
        assert admission.running == 1 and admission.waiting == 1
        assert admission.estimated_wait_s() == pytest.approx(1.5)
        third = asyncio.create_task(hold(1000.0))  # admitted: 1.5 s ahead, within 2 s
        await asyncio.sleep(0.05)
        assert admission.estimated_wait_s() == pytest.approx(2.5)
        with pytest.raises(OverloadedError) as refused:  # 2.5 s ahead: over the 2 s
            async with admission.slot(cost=10.0):
                pass
        assert refused.value.headers == {"Retry-After": "1"}  # 0.5 s until it would be admitted, rounded up
        assert "2.5 s of work ahead" in refused.value.detail
        release.set()
        await asyncio.gather(first, second, third)
        assert admission.running == admission.waiting == 0 and admission.backlog_s == pytest.approx(0.0, abs=1e-12)
        assert admission.refused == 1
        # the speed it measured: the three ran almost at once, far faster than a millisecond per cost
        assert admission.seconds_per_cost < 1e-3

    asyncio.run(scenario())


def test_no_queue_means_no_waiting() -> None:
    async def scenario() -> None:
        admission = Admission("plans", slots=1, queue=0, wait_s=10.0)
        release = asyncio.Event()

        async def hold() -> None:
            async with admission.slot(cost=1.0):
                await release.wait()

        running = asyncio.create_task(hold())
        await asyncio.sleep(0.05)
        with pytest.raises(OverloadedError):
            async with admission.slot(cost=1.0):
                pass
        release.set()
        await running

    asyncio.run(scenario())


def _burst(stack: Stack, body: dict[str, Any], count: int) -> tuple[list[httpx.Response], list[float]]:
    """``count`` concurrent plan requests, and /healthz's latencies (s) polled meanwhile."""
    latencies: list[float] = []
    done = threading.Event()

    def poll() -> None:
        with stack.client() as c:
            while not done.is_set():
                start = time.perf_counter()
                assert c.get("/healthz").status_code == 200
                latencies.append(time.perf_counter() - start)
                time.sleep(0.01)

    def post(_: int) -> httpx.Response:
        with stack.client() as c:
            return c.post("/v1/plans?fields=", json=body, timeout=120)

    poller = threading.Thread(target=poll)
    poller.start()
    try:
        with ThreadPoolExecutor(count) as pool:
            answers = list(pool.map(post, range(count)))
    finally:
        done.set()
        poller.join()
    return answers, latencies


def _p99_ms(latencies: list[float]) -> float:
    return 1e3 * statistics.quantiles(latencies, n=100)[98] if len(latencies) >= 2 else float("nan")


def test_a_burst_of_100_paper_plans_is_served_in_full(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.start_api()
    body = {"robot_id": "table1", "task": PAPER_TASK, "method": TUNED, "replay": False}
    answers, latencies = _burst(stack, body, 100)
    print(
        f"\n100 paper plans: {[r.status_code for r in answers].count(201)} answered 201; /healthz p99 {_p99_ms(latencies):.0f} ms"
    )
    assert [r.status_code for r in answers] == [201] * 100
    with stack.client() as c:
        assert c.get("/v1/plans", params={"limit": 1}).json()["total"] == 100


def test_a_burst_of_long_plans_is_served_as_far_as_the_timeout_allows(make_stack: Callable[..., Stack]) -> None:
    """20,000-step plans for two slots with a 2 s timeout: the first ones are served, the rest
    get a 503 with a Retry-After that says how long the admitted work will take to drain."""
    stack = make_stack()
    stack.env.update({"SPACEARM_MAX_CONCURRENT_PLANS": "2", "SPACEARM_PLAN_QUEUE_TIMEOUT_S": "2"})
    stack.start_api()
    body = {"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 15.0 / 20000}, "method": TUNED, "replay": False}
    with stack.client() as c:  # one first: the admission measures the speed on it
        assert c.post("/v1/plans?fields=", json=body, timeout=120).status_code == 201
    answers, latencies = _burst(stack, body, 40)
    statuses = [r.status_code for r in answers]
    print(
        f"\n40 long plans: {statuses.count(201)} answered 201, {statuses.count(503)} 503; "
        f"/healthz p99 {_p99_ms(latencies):.0f} ms"
    )
    assert set(statuses) == {201, 503} and statuses.count(201) >= 2
    for r in answers:
        if r.status_code == 503:
            assert r.headers["content-type"].startswith("application/problem+json")
            detail = r.json()["detail"]
            assert 1 <= int(r.headers["retry-after"]) <= 60
            assert "of work ahead" in detail or "ran slower than estimated" in detail, detail
    # most are refused at once, by the estimate, not after waiting
    assert sum("of work ahead" in r.text for r in answers if r.status_code == 503) >= statuses.count(503) // 2
