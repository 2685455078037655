"""Property-based fuzz of the live API with schemathesis, from its own OpenAPI document.

Every operation gets positive (schema-valid) and negative (schema-violating) requests; each
response must not be a 5xx and must conform to the document (status code, content type, body
schema). The server has no worker, so generated tuning jobs only queue (and hit 429 once the
queue is full). The totals are printed (``pytest -s``) and written to ``var/fuzz-report.json``;
``SPACEARM_FUZZ_EXAMPLES`` sets the per-operation budget (default 45 per mode).
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections import Counter
from typing import Any

import httpx
import pytest
import requests
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from hypothesis.errors import Unsatisfiable

from tests.service.conftest import ROOT, Stack

schemathesis = pytest.importorskip("schemathesis")

from schemathesis import GenerationMode  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402
from schemathesis.specs.openapi.checks import (  # noqa: E402
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance]
EXAMPLES = int(os.environ.get("SPACEARM_FUZZ_EXAMPLES", "45"))
MIN_REQUESTS = 1000
TIME_BUDGET_S = 170.0


@pytest.fixture(scope="module")
def fuzz_stack(tmp_path_factory: pytest.TempPathFactory) -> Any:
    s = Stack(tmp_path_factory.mktemp("fuzz"))
    s.env["SPACEARM_MAX_QUEUED_JOBS"] = "25"
    s.start_api()  # no worker: fuzzed tuning jobs stay queued
    yield s
    s.close()


def _is_v1_or_health(path: str) -> bool:
    return path.startswith("/v1/") or path in ("/healthz", "/readyz")


def test_fuzz_the_whole_api(fuzz_stack: Stack) -> None:
    schema = schemathesis.openapi.from_url(fuzz_stack.url + "/openapi.json")
    operations = [r.ok() for r in schema.get_all_operations()]
    operations = [op for op in operations if _is_v1_or_health(op.path)]
    assert len(operations) >= 15
    session = requests.Session()
    statuses: Counter[int] = Counter()
    server_errors: list[str] = []
    failures: list[str] = []
    started = time.monotonic()

    def run(op: Any, mode: Any, examples: int) -> None:
        @settings(
            max_examples=examples,
            deadline=None,
            database=None,
            derandomize=True,
            phases=[Phase.explicit, Phase.generate],
            suppress_health_check=list(HealthCheck),
        )
        @given(data=st.data())
        def fuzz(data: st.DataObject) -> None:
            if time.monotonic() - started > TIME_BUDGET_S:
                return
            case = data.draw(op.as_strategy(generation_mode=mode))
            try:
                response = case.call(base_url=fuzz_stack.url, session=session, timeout=30)
            except requests.RequestException as exc:  # a dropped connection counts as a server error
                statuses[0] += 1
                server_errors.append(f"{op.method.upper()} {op.path}: {type(exc).__name__}")
                return
            statuses[response.status_code] += 1
            if response.status_code >= 500:
                server_errors.append(f"{op.method.upper()} {op.path} -> {response.status_code}: {response.text[:300]}")
            try:
                case.validate_response(response, checks=CHECKS)
            except (Exception, BaseExceptionGroup) as exc:  # schemathesis reports a FailureGroup
                failures.append(f"{op.method.upper()} {op.path} [{mode.value}] -> {response.status_code}: {str(exc)[:600]}")

        with contextlib.suppress(Unsatisfiable):  # nothing to get wrong, e.g. negative requests to /healthz
            fuzz()

    for op in operations:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            run(op, mode, EXAMPLES)
    # operations with few distinct inputs (e.g. /healthz) end early; top up on the ones with bodies
    rounds = 0
    while sum(statuses.values()) < MIN_REQUESTS and rounds < 5 and time.monotonic() - started < TIME_BUDGET_S:
        rounds += 1
        for op in operations:
            if op.method.lower() == "post":
                run(op, GenerationMode.NEGATIVE if rounds % 2 else GenerationMode.POSITIVE, EXAMPLES)

    total = sum(statuses.values())
    elapsed = time.monotonic() - started
    report = {
        "requests": total,
        "operations": len(operations),
        "server_errors": len(server_errors),
        "conformance_failures": len(failures),
        "statuses": dict(sorted(statuses.items())),
        "elapsed_s": round(elapsed, 1),
        "server_error_samples": server_errors[:20],
        "failure_samples": failures[:20],
    }
    text = json.dumps(report, indent=2)
    (fuzz_stack.dir / "fuzz-report.json").write_text(text)
    (ROOT / "var").mkdir(exist_ok=True)
    (ROOT / "var" / "fuzz-report.json").write_text(text)  # the latest run's figures (var/ is not in git)
    print(f"\nschemathesis fuzz: {total} requests, {len(server_errors)} server errors, {len(failures)} failed checks")
    print(text)
    with httpx.Client(base_url=fuzz_stack.url) as c:  # the server is still healthy afterwards
        assert c.get("/healthz").status_code == 200
    assert not server_errors, text
    assert not failures, text
    assert total >= MIN_REQUESTS, text


finite = st.floats(allow_nan=False, allow_infinity=False, width=32)


@st.composite
def plan_requests(draw: st.DrawFn) -> dict[str, Any]:
    """Schema-valid plans on the Table-1 robot that reach the engine: any target, attitude,
    timing, method and parameters (short tasks, to stay quick)."""
    duration = draw(st.floats(0.5, 20.0))
    dt = draw(st.sampled_from([0.1, 0.25, 0.5, 1.0]))
    method = draw(st.sampled_from(["inverse", "dls", "adaptive", "wdls", "sdls", "svf"]))
    params = {
        "dls": {"lambda": draw(st.floats(0.0, 10.0))},
        "adaptive": {"lambda_max": draw(st.floats(0.0, 1.0)), "epsilon": draw(st.floats(1e-6, 1.0))},
    }.get(method, {})
    quaternion = draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: sum(x * x for x in q) > 1e-6))
    return {
        "robot_id": "table1",
        "task": {
            "q0_deg": draw(st.lists(st.floats(-360.0, 360.0), min_size=6, max_size=6)),
            "target_position_m": draw(st.lists(st.floats(-20.0, 20.0), min_size=3, max_size=3)),
            "target_attitude_quaternion": quaternion,
            "duration_s": duration,
            "ramp_time_s": draw(st.floats(0.0, duration / 2)),
            "dt_s": dt,
            "profile": draw(st.sampled_from(["trapezoidal", "quintic"])),
            "joint_speed_limit_deg_s": draw(st.floats(1e-3, 1e3)),
        },
        "method": {"name": method, "params": params},
        "feedback_gain": draw(st.one_of(st.just(0.0), st.floats(0.0, 1e6))),
        "aggregation": draw(st.sampled_from(["max", "rms", "final"])),
        "weights": [draw(st.floats(0.01, 10.0)), draw(st.floats(0.0, 10.0))],
        "replay": draw(st.booleans()),
    }


def test_fuzz_plans_through_the_engine(fuzz_stack: Stack) -> None:
    """Unreachable targets, degenerate timings and diverging plans are results (201 with
    ``success`` and a message), never a 5xx."""
    outcomes: Counter[str] = Counter()
    with httpx.Client(base_url=fuzz_stack.url, timeout=60) as client:

        @settings(max_examples=60, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
        @given(body=plan_requests())
        def fuzz(body: dict[str, Any]) -> None:
            r = client.post("/v1/plans", json=body)
            assert r.status_code in (201, 422), r.text
            if r.status_code == 201:
                plan = r.json()
                assert isinstance(plan["success"], bool) and plan["message"]
                outcomes["success" if plan["success"] else "failure"] += 1
            else:
                assert r.json()["errors"][0]["field"].startswith("body.")
                outcomes["422"] += 1

        fuzz()
    print(f"\nplans through the engine: {dict(outcomes)}")
    assert outcomes["failure"] > 0
