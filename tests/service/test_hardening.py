"""Limits (413, 429), bearer authentication, CORS, concurrent submissions, idempotency under
retries and crash safety, over real HTTP against uvicorn and worker subprocesses."""

from __future__ import annotations

import hashlib
import re
import signal
import sqlite3
import threading
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx

from tests.service.conftest import PAPER_TASK, Stack, job_body, wait_for, wait_status

PROBLEM = "application/problem+json"
MIB = 1024 * 1024


def _stored_jobs(stack: Stack) -> list[tuple[str, str | None]]:
    with sqlite3.connect(stack.db_path) as con:
        return list(con.execute("SELECT id, idempotency_key FROM tuning_jobs"))


# --- request size and queue limits


def test_body_over_1_mib_is_413_with_content_length(client: httpx.Client) -> None:
    big = b'{"robot_id": "table1", "pad": "' + b"x" * MIB + b'"}'
    r = client.post("/v1/plans", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413 and r.headers["content-type"].startswith(PROBLEM)
    assert r.json()["errors"][0]["field"] == "body"
    assert client.get("/healthz").status_code == 200


def test_body_over_1_mib_is_413_when_streamed_without_length(client: httpx.Client) -> None:
    def chunks() -> Iterator[bytes]:
        yield b'{"robot_id": "table1", "pad": "'
        for _ in range(20):
            yield b"x" * 65536  # 1.25 MiB in all, sent chunked
        yield b'"}'

    r = client.post("/v1/tuning-jobs", content=chunks(), headers={"content-type": "application/json"})
    assert "content-length" not in r.request.headers
    assert r.status_code == 413 and r.headers["content-type"].startswith(PROBLEM), r.text
    small = client.post("/v1/plans", content=iter([b'{"robot_id": ', b'"table1"}']), headers={"content-type": "application/json"})
    assert small.status_code == 422  # under the limit: read and validated as usual (task missing)


def test_full_queue_is_429_with_retry_after(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_MAX_QUEUED_JOBS"] = "3"
    stack.start_api()  # no worker: jobs stay queued
    with stack.client() as client:
        for i in range(3):
            assert client.post("/v1/tuning-jobs", json=job_body(), headers={"Idempotency-Key": f"q{i}"}).status_code == 202
        r = client.post("/v1/tuning-jobs", json=job_body())
        assert r.status_code == 429 and r.headers["content-type"].startswith(PROBLEM)
        assert int(r.headers["retry-after"]) > 0
        # a retry of an accepted submission still answers with its job
        again = client.post("/v1/tuning-jobs", json=job_body(), headers={"Idempotency-Key": "q1"})
        assert again.status_code == 202
        # a cancelled job frees its place
        client.post(f"/v1/tuning-jobs/{again.json()['id']}/cancel")
        assert client.post("/v1/tuning-jobs", json=job_body()).status_code == 202
    assert len(_stored_jobs(stack)) == 4


# --- authentication


KEYS = ("alpha-5bd0c1e7f3a94d2e", "beta-9e1f7c3a2b6d4085")


def test_api_keys_turn_on_bearer_auth(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_API_KEYS"] = ",".join(KEYS)
    stack.start_api()
    with stack.client() as client:
        for path in ("/v1/robots", "/v1/plans", "/v1/tuning-jobs", "/v1/task-presets/paper-line", "/v1/nothing-here"):
            r = client.get(path)
            assert r.status_code == 401, (path, r.text)
            assert r.headers["www-authenticate"].startswith("Bearer")
            assert r.headers["content-type"].startswith(PROBLEM)
        wrong = client.get("/v1/robots", headers={"Authorization": "Bearer not-a-key"})
        assert wrong.status_code == 401 and "invalid_token" in wrong.headers["www-authenticate"]
        assert client.get("/v1/robots", headers={"Authorization": f"Basic {KEYS[0]}"}).status_code == 401
        assert client.get("/v1/robots", headers={"Authorization": f"Bearer {KEYS[0]}x"}).status_code == 401
        # unauthenticated bodies are not read: no 413/422 leaks through
        assert client.post("/v1/plans", content=b"x" * (2 * MIB)).status_code == 401
        for key in KEYS:
            ok = client.get("/v1/robots/table1", headers={"Authorization": f"Bearer {key}"})
            assert ok.status_code == 200, ok.text
        job = client.post("/v1/tuning-jobs", json=job_body(), headers={"Authorization": f"bearer {KEYS[1]}"})
        assert job.status_code == 202
        for path in ("/healthz", "/readyz", "/openapi.json", "/docs"):
            assert client.get(path).status_code == 200, path
        doc = client.get("/openapi.json").json()
        scheme = doc["components"]["securitySchemes"]["bearerAuth"]
        assert scheme["type"] == "http" and scheme["scheme"] == "bearer"
        create_plan = doc["paths"]["/v1/plans"]["post"]
        assert create_plan["security"] == [{"bearerAuth": []}] and "401" in create_plan["responses"]
        assert "security" not in doc["paths"]["/healthz"]["get"]
    stack.stop_api()
    log = (stack.dir / "api.log").read_text()
    assert "authentication is on" in log
    assert not any(key in log for key in KEYS)  # keys are never logged


def test_without_keys_auth_is_off_and_logged(make_stack: Callable[..., Stack]) -> None:
    """Also: without ``SPACEARM_CORS_ORIGINS`` there is no CORS (no header grants another origin
    anything; a preflight is answered like any OPTIONS without a route for it)."""
    stack = make_stack()
    stack.env.pop("SPACEARM_API_KEYS", None)
    stack.env.pop("SPACEARM_CORS_ORIGINS", None)
    stack.start_api()
    with stack.client() as client:
        assert client.get("/v1/robots").status_code == 200
        origin = {"Origin": TOOL_ORIGIN}
        preflight = client.options("/v1/plans", headers={**origin, **_preflight("POST", "content-type")})
        simple = client.get("/v1/robots", headers=origin)
        plain = client.options("/v1/plans")
        for r in (preflight, simple, plain):
            assert not [h for h in r.headers if h.lower().startswith("access-control-")], r.headers
        assert preflight.status_code == 405 and simple.status_code == 200
        assert plain.status_code == 204 and plain.headers["allow"] == "GET, HEAD, POST, OPTIONS"
    stack.stop_api()
    log = (stack.dir / "api.log").read_text()
    assert "authentication is OFF" in log and "127.0.0.1" in log and "CORS" not in log


TOOL_ORIGIN = "http://tool.example:5173"


def _preflight(method: str, headers: str) -> dict[str, str]:
    return {"Access-Control-Request-Method": method, "Access-Control-Request-Headers": headers}


def test_cors_origins_let_a_page_of_another_origin_call_the_api(make_stack: Callable[..., Stack]) -> None:
    """With ``SPACEARM_CORS_ORIGINS`` (and keys on): a preflight from a listed origin is answered
    before authentication (it carries no key) and before the app's own OPTIONS handling; the
    requests that follow get ``Access-Control-Allow-Origin`` and can read ``Location``; another
    origin gets nothing; a plain OPTIONS still lists ``Allow``."""
    stack = make_stack()
    stack.env["SPACEARM_API_KEYS"] = KEYS[0]
    stack.env["SPACEARM_CORS_ORIGINS"] = f"{TOOL_ORIGIN}/, https://other.example"
    stack.start_api()
    auth = {"Authorization": f"Bearer {KEYS[0]}"}
    with stack.client() as client:
        ok = client.options(
            "/v1/plans", headers={"Origin": TOOL_ORIGIN, **_preflight("POST", "authorization, content-type, idempotency-key")}
        )
        assert ok.status_code == 200, ok.text
        assert ok.headers["access-control-allow-origin"] == TOOL_ORIGIN
        assert {"POST", "DELETE", "GET"} <= {m.strip() for m in ok.headers["access-control-allow-methods"].split(",")}
        allowed = {h.strip().lower() for h in ok.headers["access-control-allow-headers"].split(",")}
        assert {"authorization", "content-type", "idempotency-key"} <= allowed
        assert "access-control-allow-credentials" not in ok.headers and ok.headers["access-control-max-age"] == "600"
        stranger = client.options("/v1/plans", headers={"Origin": "http://evil.example", **_preflight("POST", "content-type")})
        assert stranger.status_code == 400 and "access-control-allow-origin" not in stranger.headers
        odd_header = client.options("/v1/plans", headers={"Origin": TOOL_ORIGIN, **_preflight("POST", "x-secret")})
        assert odd_header.status_code == 400

        body = {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "dls"}, "replay": False}
        created = client.post("/v1/plans", params={"fields": ""}, json=body, headers={"Origin": TOOL_ORIGIN, **auth})
        assert created.status_code == 201, created.text
        assert created.headers["access-control-allow-origin"] == TOOL_ORIGIN
        exposed = {h.strip().lower() for h in created.headers["access-control-expose-headers"].split(",")}
        assert {"location", "retry-after", "etag"} <= exposed and "origin" in created.headers["vary"].lower()
        other = client.get("/v1/robots", headers={"Origin": "https://other.example", **auth})
        assert other.headers["access-control-allow-origin"] == "https://other.example"
        denied = client.get("/v1/robots", headers={"Origin": TOOL_ORIGIN})  # no key: the 401 is readable
        assert denied.status_code == 401 and denied.headers["access-control-allow-origin"] == TOOL_ORIGIN
        foreign = client.get("/v1/robots", headers={"Origin": "http://evil.example", **auth})
        assert foreign.status_code == 200 and "access-control-allow-origin" not in foreign.headers
        plain = client.options("/v1/plans", headers=auth)
        assert plain.status_code == 204 and plain.headers["allow"] == "GET, HEAD, POST, OPTIONS"
    stack.stop_api()
    assert f"CORS is on for {TOOL_ORIGIN}, https://other.example" in (stack.dir / "api.log").read_text()


# --- concurrency and idempotency


def test_200_concurrent_submissions_from_50_clients_stored_once(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_MAX_QUEUED_JOBS"] = "10000"
    stack.start_api()  # no worker: every job stays queued, so the count is exact
    keys = [f"c-{uuid.uuid4().hex}" for _ in range(200)]
    statuses: Counter[int] = Counter()
    bodies: list[str] = []
    ids: dict[str, set[str]] = {k: set() for k in keys}
    lock = threading.Lock()
    barrier = threading.Barrier(50)

    def client_thread(index: int) -> None:
        mine = keys[index::50]  # 4 jobs per client
        with httpx.Client(base_url=stack.url, timeout=120) as c:
            barrier.wait()
            for key in mine:
                for _attempt in range(2):  # every submission is retried once with the same key
                    r = c.post("/v1/tuning-jobs", json=job_body(), headers={"Idempotency-Key": key})
                    with lock:
                        statuses[r.status_code] += 1
                        bodies.append(r.text)
                        if r.status_code == 202:
                            ids[key].add(r.json()["id"])

    with ThreadPoolExecutor(50) as pool:
        list(pool.map(client_thread, range(50)))
    print(f"\nconcurrent submissions: 400 requests (200 jobs, each retried once) from 50 clients: {dict(statuses)}")
    assert statuses == {202: 400}, (statuses, [b for b in bodies if '"id"' not in b][:3])
    assert not any("locked" in b for b in bodies)
    assert all(len(v) == 1 for v in ids.values())  # a retry got the same job
    stored = _stored_jobs(stack)
    print(f"stored: {len(stored)} jobs, {len({k for _, k in stored})} distinct keys")
    assert len(stored) == 200
    assert {k for _, k in stored} == set(keys)
    assert {i for i, _ in stored} == set().union(*ids.values())
    with stack.client() as c:
        assert c.get("/v1/tuning-jobs", params={"status": "queued", "limit": 1}).json()["total"] == 200


def test_idempotency_key_retries_never_create_a_second_job(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.start_api()
    barrier = threading.Barrier(20)

    def submit(_: int) -> httpx.Response:
        with httpx.Client(base_url=stack.url, timeout=60) as c:
            barrier.wait()
            return c.post("/v1/tuning-jobs", json=job_body(), headers={"Idempotency-Key": "same-key"})

    with ThreadPoolExecutor(20) as pool:
        responses = list(pool.map(submit, range(20)))
    assert {r.status_code for r in responses} == {202}
    assert len({r.json()["id"] for r in responses}) == 1
    assert len({r.headers["location"] for r in responses}) == 1
    first = responses[0].json()["id"]
    stack.stop_api()  # later retries, even after the API restarted, get the same job too
    stack.start_api()
    with stack.client() as c:
        for _ in range(3):
            assert c.post("/v1/tuning-jobs", json=job_body(), headers={"Idempotency-Key": "same-key"}).json()["id"] == first
    assert [k for _, k in _stored_jobs(stack)] == ["same-key"]


# --- crash safety


def test_job_failing_on_every_attempt_ends_failed(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack(lease_seconds=1.0)
    stack.env["SPACEARM_JOB_MAX_ATTEMPTS"] = "2"
    stack.start_api()
    with stack.client() as client:
        job = client.post("/v1/tuning-jobs", json=job_body(population=8, generations=500, compare=False)).json()
        assert job["max_attempts"] == 2
        for attempt in (1, 2):  # the worker dies in the middle of every attempt
            worker = stack.start_worker()
            wait_for(
                lambda a=attempt: (
                    (j := client.get(f"/v1/tuning-jobs/{job['id']}").json())["attempts"] == a
                    and j["status"] == "running"
                    and j["progress"]["generation"] >= 2
                ),
                timeout=60,
            )
            worker.stop(signal.SIGKILL)
        stack.start_worker()  # finds the lease expired with no attempts left
        failed = wait_status(client, job["id"], ("failed", "succeeded"), timeout=30)
        assert failed["status"] == "failed" and failed["attempts"] == 2
        assert "attempts" in failed["error"] and failed["finished_at"]
        r = client.get(f"/v1/tuning-jobs/{job['id']}/result")
        assert r.status_code == 409 and "attempts" in r.json()["detail"]


def _csrf(page: httpx.Response) -> str:
    match = re.search(r'name="csrf_token" value="([^"]+)"', page.text)
    assert match, "the page's forms carry a CSRF token"
    return match.group(1)


def test_web_sessions_csrf_and_page_headers_when_keys_are_on(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_API_KEYS"] = ",".join(KEYS)
    stack.start_api()
    auth = {"Authorization": f"Bearer {KEYS[0]}"}
    with stack.client() as client:
        plan = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "replay": False}, headers=auth).json()
        # Pages read the database directly: without a session they send the browser to sign in.
        for path in ("/", f"/plans/{plan['id']}"):
            r = client.get(path, follow_redirects=False)
            assert r.status_code == 303 and r.headers["location"].startswith("/login"), path
        login_page = client.get("/login")
        assert login_page.status_code == 200
        assert "default-src 'self'" in login_page.headers["content-security-policy"]
        assert "'unsafe-inline'" not in login_page.headers["content-security-policy"]
        assert login_page.headers["x-frame-options"] == "DENY" and login_page.headers["x-content-type-options"] == "nosniff"
        assert login_page.headers["referrer-policy"] == "same-origin"
        token = _csrf(login_page)
        assert client.cookies.get("spacearm_csrf") == token  # double-submitted before a session exists
        # Login CSRF: a form without the token, or from another site, is refused.
        assert client.post("/login", data={"key": KEYS[1], "next": "/"}, follow_redirects=False).status_code == 403
        evil = {"origin": "https://evil.example"}
        forged = client.post("/login", data={"key": KEYS[1], "csrf_token": token}, headers=evil, follow_redirects=False)
        assert forged.status_code == 403
        bad = client.post("/login", data={"key": "nope", "next": "/", "csrf_token": token}, follow_redirects=False)
        assert bad.status_code == 401 and "spacearm_session" not in bad.headers.get("set-cookie", "")
        ok = client.post(
            "/login", data={"key": KEYS[1], "next": "https://evil.example/", "csrf_token": token}, follow_redirects=False
        )
        assert ok.status_code == 303 and ok.headers["location"] == "/"  # no open redirect
        cookie = ok.headers["set-cookie"]
        assert "httponly" in cookie.lower() and "samesite=strict" in cookie.lower() and "secure" not in cookie.lower()
        session = client.cookies.get("spacearm_session")
        assert session and KEYS[1] not in cookie  # a random session id, never the key
        with sqlite3.connect(stack.db_path) as con:
            stored = [row[0] for row in con.execute("SELECT id FROM web_sessions")]
        assert stored == [hashlib.sha256(session.encode()).hexdigest()]  # only its hash is stored
        index = client.get("/")
        assert index.status_code == 200 and index.headers["x-frame-options"] == "DENY"
        assert client.get(f"/plans/{plan['id']}").status_code == 200
        # The session opens reads under /v1 (figures, job progress) but not writes.
        assert client.get(f"/v1/plans/{plan['id']}/figures/joint-angles").status_code == 200
        assert client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK}).status_code == 401
        # The page's own form is forwarded to the API once its CSRF token checks out.
        form = {"preset": "paper-line", "method": "dls", "dls.lambda": "0.05"}
        assert client.post("/web/plans", data=form, follow_redirects=False).status_code == 403
        assert client.post("/web/plans", data={**form, "csrf_token": "x" * 43}, follow_redirects=False).status_code == 403
        form["csrf_token"] = _csrf(index)
        cross = client.post("/web/plans", data=form, headers={"referer": "https://evil.example/page"}, follow_redirects=False)
        assert cross.status_code == 403
        sandboxed = client.post("/web/plans", data=form, headers={"origin": "null"}, follow_redirects=False)
        assert sandboxed.status_code == 403  # an opaque origin (sandboxed frame, file:) is another site
        submitted = client.post("/web/plans", data=form, headers={"origin": stack.url}, follow_redirects=False)
        assert submitted.status_code == 303 and submitted.headers["location"].startswith("/plans/")
        # Sign out revokes the session server-side: the same cookie opens nothing afterwards.
        out_token = _csrf(client.get("/logout"))
        assert client.post("/logout", data={"csrf_token": out_token}, follow_redirects=False).status_code == 303
        client.cookies.set("spacearm_session", session)
        assert client.get("/", follow_redirects=False).status_code == 303
        assert client.get("/v1/plans").status_code == 401
        with sqlite3.connect(stack.db_path) as con:
            assert con.execute("SELECT count(*) FROM web_sessions").fetchone() == (0,)
    # A session ends when its key is removed from the configuration; cookies are Secure on request.
    with stack.client() as client:
        token = _csrf(client.get("/login"))
        assert client.post("/login", data={"key": KEYS[1], "csrf_token": token}, follow_redirects=False).status_code == 303
        session = client.cookies.get("spacearm_session")
    stack.stop_api()
    stack.env["SPACEARM_API_KEYS"] = KEYS[0]
    stack.env["SPACEARM_COOKIE_SECURE"] = "true"
    stack.start_api()
    with stack.client() as client:
        client.cookies.set("spacearm_session", session or "")
        assert client.get("/", follow_redirects=False).status_code == 303
        # (over plain HTTP a client does not send Secure cookies back: here only their flags are checked)
        assert "secure" in client.get("/login").headers["set-cookie"].lower()
