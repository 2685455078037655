"""A job's life as a client sees it, over real HTTP and real processes: the Server-Sent Events
stream (several API processes, resume, heartbeats, cancel), the per-phase progress, links,
deletion, retention (the README's quick start, with its tuning job: tests/service/test_quickstart.py)."""

from __future__ import annotations

import json
import re
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx

from tests.service.conftest import PAPER_TASK, Proc, Stack, free_port, job_body, wait_for, wait_status


def sse(response: httpx.Response) -> Iterator[dict[str, Any]]:
    """The events of a ``text/event-stream`` response, as dicts (event, id, data, comment)."""
    event: dict[str, Any] = {}
    for line in response.iter_lines():
        if not line:
            if event:
                yield event
            event = {}
            continue
        field, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if field == "":
            event["comment"] = value
        elif field == "data":
            event["data"] = json.loads(value)
        else:
            event[field] = value
    if event:
        yield event


def stream(client: httpx.Client, job_id: str, headers: dict[str, str] | None = None, **params: str) -> list[dict[str, Any]]:
    with client.stream("GET", f"/v1/tuning-jobs/{job_id}/events", headers=headers, params=params, timeout=120) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        return list(sse(r))


def start_second_api(stack: Stack) -> tuple[Proc, str]:
    port = free_port()
    proc = Proc(["serve", "--host", "127.0.0.1", "--port", str(port)], stack.env, stack.dir / "api2.log")
    url = f"http://127.0.0.1:{port}"
    wait_for(lambda: _ready(url), timeout=300, interval=0.2)
    return proc, url


def _ready(url: str) -> bool:
    try:
        return bool(httpx.get(url + "/readyz", timeout=1).json().get("kernels") == "ok")
    except (httpx.HTTPError, ValueError):
        return False


def test_events_follow_a_job_from_another_api_process_and_resume(make_stack: Callable[..., Stack]) -> None:
    """Submitted through one API process, run by a worker, streamed from a second API process
    (the stream reads the database): every generation of both phases once, in order, with ids
    1.1 ... 1.10, then the final status and ``end``, and the stream closes. A reconnect with
    ``Last-Event-ID`` gets what came after; an id the job never sent is a 422."""
    stack = make_stack()
    stack.start_api()
    other, other_url = start_second_api(stack)
    try:
        with stack.client() as c, httpx.Client(base_url=other_url, timeout=60) as c2:
            job = c.post("/v1/tuning-jobs", json=job_body(population=10, generations=4)).json()
            assert job["links"]["events"] == f"/v1/tuning-jobs/{job['id']}/events"
            stack.start_worker()  # after the stream below could open: it sees queued, then the run
            events = stream(c2, job["id"])
            kinds = [e.get("event") for e in events if "event" in e]
            assert kinds[0] == "status" and events[0]["data"]["status"] in ("queued", "running")
            assert kinds[-2:] == ["status", "end"] and events[-1]["data"]["status"] == "succeeded"
            generations = [e for e in events if e.get("event") == "generation"]
            assert [e["id"] for e in generations] == [f"1.{n}" for n in range(1, 11)]
            assert [(g["data"]["role"], g["data"]["generation"]) for g in generations] == [
                (role, n) for role in ("tuned", "dls_baseline") for n in range(5)
            ]
            assert all(g["data"]["generations"] == 4 and g["data"]["stage"] == "ga" for g in generations)
            final = [e for e in events if e.get("event") == "status"][-1]["data"]
            assert final["generation"] == final["generations"] == 8

            resumed = stream(c2, job["id"], headers={"Last-Event-ID": "1.7"})
            assert [e["id"] for e in resumed if e.get("event") == "generation"] == ["1.8", "1.9", "1.10"]
            assert resumed[0]["event"] == "status" and resumed[-1]["event"] == "end"  # the job's state first
            # a refined job: the refinement's rounds are generation events of stage refine, numbered on
            refined = c.post("/v1/tuning-jobs", json={**job_body(population=6, generations=2, compare=False), "refine": True})
            rows = [e["data"] for e in stream(c2, refined.json()["id"]) if e.get("event") == "generation"]
            assert [r["stage"] for r in rows[:3]] == ["ga"] * 3 and {r["stage"] for r in rows[3:]} == {"refine"}
            assert len(rows) > 3 and [r["generation"] for r in rows[2:5]] == [2, 3, 4]
            by_query = stream(c, job["id"], last_event_id="1.10")
            assert [e.get("event") for e in by_query] == ["status", "end"]
            for bad in ("1.11", "2.1", "x", "1"):
                r = c.get(f"/v1/tuning-jobs/{job['id']}/events", headers={"Last-Event-ID": bad})
                assert r.status_code == 422 and r.json()["errors"][0]["field"] == "header.Last-Event-ID", bad
            assert c.get(f"/v1/tuning-jobs/{'0' * 32}/events").status_code == 404
            assert c.get("/v1/tuning-jobs/nope/events").status_code == 404
    finally:
        other.stop()


def test_events_beat_while_queued_and_end_when_cancelled(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_SSE_HEARTBEAT_S"] = "0.5"
    stack.start_api()  # no worker: the job stays queued
    with stack.client() as c:
        job_id = c.post("/v1/tuning-jobs", json=job_body()).json()["id"]
        seen: list[dict[str, Any]] = []
        with c.stream("GET", f"/v1/tuning-jobs/{job_id}/events", timeout=60) as r:
            started = time.monotonic()
            for event in sse(r):
                seen.append(event)
                beats = sum(1 for e in seen if e.get("comment") == "heartbeat")
                if beats == 2 and time.monotonic() - started < 30:
                    assert c.post(f"/v1/tuning-jobs/{job_id}/cancel").status_code == 202
    kinds = [e.get("event", "comment") for e in seen]
    print(f"\nqueued job stream: {kinds}")
    assert kinds[0] == "status" and seen[0]["data"]["status"] == "queued"
    assert kinds.count("comment") >= 2
    assert kinds[-2:] == ["status", "end"] and seen[-1]["data"]["status"] == "cancelled"


def test_job_progress_has_phases_that_add_up_and_links_that_work(client: httpx.Client) -> None:
    job = client.post("/v1/tuning-jobs", json=job_body(population=6, generations=3)).json()
    done = wait_status(client, job["id"], ("succeeded",))
    progress = done["progress"]
    phases = progress["phases"]
    assert [(p["name"], p["role"], p["generations"], p["completed"]) for p in phases] == [
        ("adaptive", "tuned", 3, 3),
        ("dls", "dls_baseline", 3, 3),
    ]
    assert [[h["generation"] for h in p["history"]] for p in phases] == [[0, 1, 2, 3]] * 2
    assert progress["generation"] == progress["generations"] == sum(p["generations"] for p in phases) == 6
    assert "history" not in progress
    links = done["links"]
    assert client.get(links["self"]).json()["id"] == job["id"]
    result = client.get(links["result"]).json()
    assert isinstance(result["warnings"], list) and isinstance(result["dls_baseline"]["warnings"], list)
    assert client.get(links["convergence_figure"]).headers["content-type"].startswith("image/svg+xml")


def test_delete_plans_and_jobs(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack(lease_seconds=3.0)
    stack.start_api()
    with stack.client() as c:
        plan_id = c.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": PAPER_TASK}).json()["id"]
        assert c.delete(f"/v1/plans/{plan_id}").status_code == 204
        assert c.get(f"/v1/plans/{plan_id}").status_code == 404
        assert c.get(f"/v1/plans/{plan_id}/figures/damping").status_code == 404
        assert c.delete(f"/v1/plans/{plan_id}").status_code == 404
        assert c.delete(f"/v1/plans/{'0' * 32}").json()["status"] == 404

        queued = c.post("/v1/tuning-jobs", json=job_body()).json()["id"]
        assert c.delete(f"/v1/tuning-jobs/{queued}").status_code == 204
        assert c.get(f"/v1/tuning-jobs/{queued}").status_code == 404
        assert c.delete(f"/v1/tuning-jobs/{queued}").status_code == 404

        # a running job: its worker notices it is gone, stops, and takes the next job
        long = c.post("/v1/tuning-jobs", json=job_body(population=400, generations=60, dt_s=0.05)).json()["id"]
        worker = stack.start_worker()
        wait_status(c, long, ("running",))
        wait_for(lambda: c.get(f"/v1/tuning-jobs/{long}").json()["progress"]["generation"] >= 1, timeout=60)
        deleted_at = time.monotonic()
        assert c.delete(f"/v1/tuning-jobs/{long}").status_code == 204
        wait_for(lambda: "stopped: lost" in worker.log.read_text() or "stopped: cancel" in worker.log.read_text(), 30)
        print(f"\nworker stopped the deleted job after {time.monotonic() - deleted_at:.2f} s")
        after = c.post("/v1/tuning-jobs", json=job_body()).json()["id"]
        assert wait_status(c, after, ("succeeded",))["status"] == "succeeded"
        assert worker.popen.poll() is None


def test_retention_deletes_old_finished_jobs_and_plans(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env.update({"SPACEARM_RETENTION_DAYS": str(10.0 / 86400), "SPACEARM_RETENTION_SWEEP_S": "0.5"})
    stack.start_api()
    with stack.client() as c:
        plan_id = c.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": PAPER_TASK}).json()["id"]
        finished = c.post("/v1/tuning-jobs", json=job_body()).json()["id"]
        c.post(f"/v1/tuning-jobs/{finished}/cancel")  # a queued job cancelled: finished at once
        waiting = c.post("/v1/tuning-jobs", json=job_body(population=5)).json()["id"]
        assert c.get(f"/v1/plans/{plan_id}").status_code == 200  # younger than 10 s
        wait_for(lambda: c.get(f"/v1/plans/{plan_id}").status_code == 404, timeout=40, interval=0.2)
        wait_for(lambda: c.get(f"/v1/tuning-jobs/{finished}").status_code == 404, timeout=30, interval=0.2)
        assert c.get(f"/v1/tuning-jobs/{waiting}").json()["status"] == "queued"  # never deleted while queued
    stack.stop_api()
    # the plan and the job may expire in different sweeps (on a loaded machine): count them all
    sweeps = re.findall(r"retention: deleted (\d+) plan\(s\) and (\d+) finished job\(s\)", (stack.dir / "api.log").read_text())
    assert (sum(int(p) for p, _ in sweeps), sum(int(j) for _, j in sweeps)) == (1, 1), sweeps
