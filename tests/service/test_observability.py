"""Observability over real processes: ``/metrics`` (counters move by exactly what was done, the
queue and worker metrics follow the database), ``X-Request-ID`` in responses and log lines, JSON
logs of the API and the worker, and the redaction of secrets in both log formats."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from tests.service.conftest import PAPER_TASK, Stack, job_body, wait_for, wait_status

HEX32 = re.compile(r"[0-9a-f]{32}")
LEASE_S = 30.0
Samples = dict[tuple[str, tuple[tuple[str, str], ...]], float]


def scrape(client: httpx.Client) -> Samples:
    response = client.get("/metrics")
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("text/plain; version=0.0.4")
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(response.text)
        for s in family.samples
    }


def value(samples: Samples, name: str, **labels: str) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def labelled(samples: Samples, name: str) -> list[dict[str, str]]:
    return [dict(labels) for (n, labels) in samples if n == name]


def json_lines(path: Path) -> list[dict[str, Any]]:
    """Every line of a JSON log, parsed (a line that is not JSON fails the test)."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def json_stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    """API and one worker logging JSON, with a lease long enough to assert heartbeat ages under it."""
    s = Stack(tmp_path_factory.mktemp("obs"), lease_seconds=LEASE_S)
    s.env["SPACEARM_LOG_FORMAT"] = "json"
    s.start_api()
    s.start_worker()
    yield s
    s.close()


@pytest.fixture
def api(json_stack: Stack) -> Iterator[httpx.Client]:
    with json_stack.client() as c:
        yield c


def plan_body(name: str, params: dict[str, float]) -> dict[str, Any]:
    return {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": name, "params": params}}


def test_request_and_plan_counters_move_by_what_was_done(api: httpx.Client) -> None:
    before = scrape(api)
    for _ in range(3):
        assert api.get("/v1/robots/table1").status_code == 200
    for plan_id in (f"{i:032x}" for i in range(2)):
        assert api.get(f"/v1/plans/{plan_id}").status_code == 404
    assert api.head("/v1/robots/table1").status_code == 200
    assert api.post("/v1/plans?fields=", json=plan_body("dls", {"lambda": 0.05})).status_code == 201
    assert api.post("/v1/plans?fields=", json=plan_body("adaptive", {"lambda_max": 0.06, "epsilon": 0.12})).status_code == 201
    # an unreachable speed limit: stored, success false
    infeasible = plan_body("dls", {"lambda": 0.05})
    infeasible["task"] = {**PAPER_TASK, "joint_speed_limit_deg_s": 0.001}
    stored = api.post("/v1/plans?fields=", json=infeasible)
    assert stored.status_code == 201 and stored.json()["success"] is False
    assert api.post("/v1/plans", json=plan_body("dls", {"nope": 1.0})).status_code == 422  # not a plan
    after = scrape(api)

    def delta(name: str, **labels: str) -> float:
        return value(after, name, **labels) - value(before, name, **labels)

    requests = "spacearm_http_requests_total"
    assert delta(requests, method="GET", route="/v1/robots/{robot_id}", status="200") == 3
    assert delta(requests, method="GET", route="/v1/plans/{plan_id}", status="404") == 2
    assert delta(requests, method="HEAD", route="/v1/robots/{robot_id}", status="200") == 1
    assert delta(requests, method="POST", route="/v1/plans", status="201") == 3
    assert delta(requests, method="POST", route="/v1/plans", status="422") == 1
    assert delta(requests, method="GET", route="/metrics", status="200") == 1  # the first scrape (this one is in flight)
    latency = "spacearm_http_request_duration_seconds"
    assert delta(latency + "_count", method="POST", route="/v1/plans", status="201") == 3
    assert delta(latency + "_sum", method="POST", route="/v1/plans", status="201") > 0
    assert delta(latency + "_bucket", method="POST", route="/v1/plans", status="201", le="+Inf") == 3
    # no raw ids in the route label
    assert not any(HEX32.search(labels["route"]) for labels in labelled(after, requests))
    assert value(after, "spacearm_http_requests_in_progress") == 1  # the scrape itself

    plans = "spacearm_plans_computed_total"
    assert delta(plans, method="dls", success="true") == 1
    assert delta(plans, method="dls", success="false") == 1
    assert delta(plans, method="adaptive", success="true") == 1
    assert sum(v for (n, _), v in after.items() if n == plans) - sum(v for (n, _), v in before.items() if n == plans) == 3
    assert delta("spacearm_plan_compute_seconds_count", method="adaptive") == 1
    assert value(after, "process_resident_memory_bytes") > 0
    assert value(after, "spacearm_metrics_database_up") == 1


def test_metrics_is_documented_as_text_and_open_without_keys(api: httpx.Client) -> None:
    op = api.get("/openapi.json").json()["paths"]["/metrics"]["get"]
    assert set(op["responses"]["200"]["content"]) == {"text/plain"}
    assert "security" not in op and "401" not in op["responses"]  # open, as the API is without keys


def test_queue_heartbeat_and_duration_metrics_follow_the_database(json_stack: Stack, api: httpx.Client) -> None:
    before = scrape(api)
    done = api.post("/v1/tuning-jobs", json=job_body(population=4, generations=2)).json()
    done = wait_status(api, done["id"], ("succeeded",))
    long = api.post("/v1/tuning-jobs", json=job_body(population=20, generations=1000)).json()
    wait_status(api, long["id"], ("running",))
    waiting = api.post("/v1/tuning-jobs", json=job_body(population=4, generations=2)).json()  # the only worker is busy
    during = scrape(api)
    assert value(during, "spacearm_tuning_jobs", status="running") == 1
    assert value(during, "spacearm_tuning_jobs", status="queued") == 1
    succeeded = value(during, "spacearm_tuning_jobs", status="succeeded")
    assert succeeded - value(before, "spacearm_tuning_jobs", status="succeeded") == 1
    assert value(during, "spacearm_tuning_jobs_oldest_queued_age_seconds") > 0
    assert value(during, "spacearm_workers_busy") == 1
    assert value(during, "spacearm_tuning_jobs_lease_expired") == 0
    (worker,) = labelled(during, "spacearm_worker_heartbeat_age_seconds")
    _host, pid, _ = worker["worker"].split(":")
    assert int(pid) == json_stack.workers[0].popen.pid
    # renewed every second by a live worker: well within the lease
    assert 0 <= value(during, "spacearm_worker_heartbeat_age_seconds", **worker) < LEASE_S

    for job in (waiting, long):  # the queued one first: it never starts
        assert api.post(f"/v1/tuning-jobs/{job['id']}/cancel").status_code in (200, 202)
        wait_status(api, job["id"], ("cancelled",))
    after = scrape(api)
    duration = "spacearm_tuning_job_duration_seconds"

    def delta(name: str, **labels: str) -> float:
        return value(after, name, **labels) - value(before, name, **labels)

    # the queued job was cancelled before it started: it has no run time
    assert delta(duration + "_gcount", status="cancelled") == 1
    assert delta(duration + "_gcount", status="succeeded") == 1
    ran = (datetime.fromisoformat(done["finished_at"]) - datetime.fromisoformat(done["started_at"])).total_seconds()
    assert delta(duration + "_gsum", status="succeeded") == pytest.approx(ran, abs=2e-3)
    assert delta(duration + "_bucket", status="succeeded", le="+Inf") == 1
    assert value(after, "spacearm_tuning_jobs", status="running") == 0
    assert value(after, "spacearm_workers_busy") == 0
    assert labelled(after, "spacearm_worker_heartbeat_age_seconds") == []


def test_request_ids_are_echoed_and_in_the_json_access_log(json_stack: Stack, api: httpx.Client) -> None:
    given = api.get("/v1/robots/table1", headers={"X-Request-ID": "client-id-42"})
    assert given.headers["x-request-id"] == "client-id-42"
    generated = api.get("/v1/robots/table1")
    assert HEX32.fullmatch(generated.headers["x-request-id"])
    for bad in (b"a" * 129, b"has space", b"tab\tin", "é".encode()):
        replaced = api.get("/healthz", headers={"X-Request-ID": bad})
        assert HEX32.fullmatch(replaced.headers["x-request-id"]), bad
    # errors, answers of the guards, methods and the not-found page carry it too
    cases = [
        api.get("/v1/plans/" + "0" * 32, headers={"X-Request-ID": "e-404"}),
        api.post("/v1/plans", json={}, headers={"X-Request-ID": "e-422"}),
        api.post("/v1/plans", content=b"x" * (1024 * 1024 + 1), headers={"X-Request-ID": "e-413"}),
        api.delete("/v1/robots", headers={"X-Request-ID": "e-405"}),
        api.options("/v1/plans", headers={"X-Request-ID": "e-options"}),
        api.get("/no/such/page", headers={"X-Request-ID": "e-unrouted"}),
    ]
    assert [r.status_code for r in cases] == [404, 422, 413, 405, 204, 404]
    assert [r.headers["x-request-id"] for r in cases] == ["e-404", "e-422", "e-413", "e-405", "e-options", "e-unrouted"]
    secret = api.get("/v1/robots/table1?api_key=hunter2&x=1", headers={"X-Request-ID": "with-secret"})
    assert secret.status_code == 200

    def access(request_id: str) -> dict[str, Any] | None:
        lines = [e for e in json_lines(json_stack.dir / "api.log") if e.get("request_id") == request_id]
        return lines[0] if lines else None

    line = wait_for(lambda: access("client-id-42"))
    assert line["logger"] == "uvicorn.access" and line["level"] == "INFO"
    assert line["method"] == "GET" and line["path"] == "/v1/robots/table1" and line["status_code"] == 200
    assert datetime.fromisoformat(line["time"]).utcoffset() is not None
    assert wait_for(lambda: access(generated.headers["x-request-id"]))["status_code"] == 200
    assert wait_for(lambda: access("e-413"))["status_code"] == 413
    redacted = wait_for(lambda: access("with-secret"))
    assert redacted["path"] == "/v1/robots/table1?api_key=[redacted]&x=1"
    assert "[redacted]" in redacted["message"]
    assert "hunter2" not in (json_stack.dir / "api.log").read_text()
    # every line outside a request has request_id null, and every line is an object with the core fields
    for entry in json_lines(json_stack.dir / "api.log"):
        assert {"time", "level", "logger", "message", "request_id"} <= entry.keys(), entry


def test_worker_json_log_has_the_job_id_and_every_generation(json_stack: Stack, api: httpx.Client) -> None:
    generations = 3
    job = api.post("/v1/tuning-jobs", json=job_body(population=4, generations=generations)).json()
    wait_status(api, job["id"], ("succeeded",))
    log = json_stack.workers[0].log

    def lines() -> list[dict[str, Any]] | None:
        found = [e for e in json_lines(log) if e.get("job_id") == job["id"]]
        return found if any(e["message"].endswith(": succeeded") for e in found) else None

    entries = wait_for(lines)
    assert all(e["logger"] == "spacearm.worker" and {"time", "level", "message"} <= e.keys() for e in entries)
    seen: dict[str, set[int]] = {}
    for entry in entries:
        match = re.search(r": (\w+) generation (\d+)/(\d+), best B ([0-9.e+-]+)", entry["message"])
        if match:
            assert entry["level"] == "INFO" and job["id"] in entry["message"]
            assert int(match.group(3)) == generations and float(match.group(4)) > 0
            seen.setdefault(match.group(1), set()).add(int(match.group(2)))
    assert set(seen) == {"adaptive", "dls"}
    assert all(set(range(1, generations + 1)) <= numbers for numbers in seen.values())
    # lines outside a job have no job_id
    assert any("polling" in e["message"] and "job_id" not in e for e in json_lines(log))


def test_text_logs_carry_the_request_id_and_metrics_follow_the_keys(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_API_KEYS"] = "k-one"
    stack.start_api()
    with stack.client() as client:
        denied = client.get("/metrics", headers={"X-Request-ID": "no-key"})
        assert denied.status_code == 401 and denied.headers["x-request-id"] == "no-key"
        assert client.get("/metrics", headers={"Authorization": "Bearer wrong"}).status_code == 401
        auth = {"Authorization": "Bearer k-one"}
        assert client.get("/metrics", headers=auth).status_code == 200
        r = client.get("/v1/robots/table1?token=sesame", headers={**auth, "X-Request-ID": "text-id-7"})
        assert r.status_code == 200 and r.headers["x-request-id"] == "text-id-7"
        client.headers.update(auth)
        samples = scrape(client)
    # a 401 answered before routing is counted, under <unrouted>
    assert value(samples, "spacearm_http_requests_total", method="GET", route="<unrouted>", status="401") == 2
    doc = httpx.get(stack.url + "/openapi.json").json()
    assert doc["paths"]["/metrics"]["get"]["security"] == [{"bearerAuth": []}]
    stack.stop_api()
    text = (stack.dir / "api.log").read_text()
    (line,) = [line for line in text.splitlines() if "[request_id=text-id-7]" in line]
    assert '"GET /v1/robots/table1?token=[redacted] HTTP/1.1" 200' in line and "uvicorn.access" in line
    assert "sesame" not in text and "k-one" not in text


def test_admission_503s_carry_their_request_id_and_are_counted(make_stack: Callable[..., Stack]) -> None:
    """A plan refused by admission control (one slot, no queue) still echoes its X-Request-ID, is
    logged with it and is counted under its route and status 503."""
    stack = make_stack()
    stack.env.update({"SPACEARM_MAX_CONCURRENT_PLANS": "1", "SPACEARM_PLAN_QUEUE": "0"})
    stack.start_api()
    body = plan_body("dls", {"lambda": 0.05})
    body["task"] = {**PAPER_TASK, "dt_s": 0.005}  # 3000 steps: long enough for concurrent ones to meet

    def post(request_id: str) -> httpx.Response:
        with stack.client() as c:
            return c.post("/v1/plans?fields=", json=body, headers={"X-Request-ID": request_id})

    refused: list[httpx.Response] = []
    with ThreadPoolExecutor(6) as pool:
        for round_ in range(5):  # until some overlap (every round has six at once for one slot)
            answers = list(pool.map(post, [f"r{round_}-{i}" for i in range(6)]))
            assert {r.status_code for r in answers} <= {201, 503}
            assert [r.headers["x-request-id"] for r in answers] == [f"r{round_}-{i}" for i in range(6)]
            refused += [r for r in answers if r.status_code == 503]
            if refused:
                break
    assert refused, "six concurrent plans for one slot and no queue were all admitted, five rounds in a row"
    for r in refused:
        assert int(r.headers["retry-after"]) > 0 and r.headers["content-type"].startswith("application/problem+json")
    with stack.client() as c:
        samples = scrape(c)
    assert value(samples, "spacearm_http_requests_total", method="POST", route="/v1/plans", status="503") == len(refused)
    stack.stop_api()
    log = (stack.dir / "api.log").read_text().splitlines()
    for r in refused:
        (line,) = [line for line in log if f"[request_id={r.headers['x-request-id']}]" in line and "uvicorn.access" in line]
        assert '"POST /v1/plans?fields= HTTP/1.1" 503' in line


def test_two_api_processes_agree_on_the_database_metrics_and_count_their_own_requests(
    make_stack: Callable[..., Stack],
) -> None:
    first = make_stack()
    second = make_stack(database_url=first.database_url)  # another API process on the same database
    for stack in (first, second):
        stack.start_api()
    with first.client() as one, second.client() as two:
        before = [scrape(one), scrape(two)]
        ids = [one.post("/v1/tuning-jobs", json=job_body()).json()["id"] for _ in range(3)]  # no worker: queued
        assert two.post(f"/v1/tuning-jobs/{ids[0]}/cancel").status_code in (200, 202)
        after = [scrape(one), scrape(two)]
    jobs = "spacearm_tuning_jobs"
    for samples, earlier in zip(after, before, strict=True):  # both read the one database
        assert value(samples, jobs, status="queued") - value(earlier, jobs, status="queued") == 2
        assert value(samples, jobs, status="cancelled") == 1

    def requests(samples: Samples, route: str) -> float:  # any status
        return sum(v for (n, labels), v in samples.items() if n == "spacearm_http_requests_total" and ("route", route) in labels)

    # each process counts only what it answered
    assert [requests(s, "/v1/tuning-jobs") for s in after] == [3, 0]
    assert [requests(s, "/v1/tuning-jobs/{job_id}/cancel") for s in after] == [0, 1]
