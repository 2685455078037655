"""Property-based fuzz of the live API with schemathesis, from its own OpenAPI document.

The schemathesis CLI runs every phase: the document's examples, coverage (boundary values and
each constraint violated in turn), fuzzing (positive and negative requests) and stateful
sequences that follow the document's links (create a robot, plan or job, then read, figure,
cancel or delete it). Every check is on: no 5xx, status codes, content types, headers and
bodies as documented, negative data rejected, schema-valid data accepted (for the operations of
``schemathesis.toml`` a 422 is allowed: physics the schema cannot state), ``Allow`` headers,
authentication. The server has no worker, so generated tuning jobs only queue (and hit 429 once
the queue is full). The totals are written to ``var/fuzz-report.json``;
``SPACEARM_FUZZ_EXAMPLES`` sets the per-operation budget of the generating phases (default 120).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tomllib
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.service.conftest import ROOT, Stack

pytest.importorskip("schemathesis")

EXAMPLES = int(os.environ.get("SPACEARM_FUZZ_EXAMPLES", "50"))
MIN_REQUESTS = 5000
CONFIG = Path(__file__).with_name("schemathesis.toml")
PHASES = ("examples", "coverage", "fuzzing", "stateful")
ACCESS_LINE = re.compile(r'"[A-Z]+ [^"]*HTTP/[0-9.]+" (\d{3})')


@pytest.fixture(scope="module")
def fuzz_stack(tmp_path_factory: pytest.TempPathFactory) -> Any:
    s = Stack(tmp_path_factory.mktemp("fuzz"))
    s.env["SPACEARM_MAX_QUEUED_JOBS"] = "25"
    s.start_api()  # no worker: fuzzed tuning jobs stay queued
    yield s
    s.close()


def _statuses(log: Path) -> Counter[int]:
    """The status codes of the API's access log."""
    return Counter(int(m.group(1)) for m in ACCESS_LINE.finditer(log.read_text(errors="replace")))


def test_fuzz_the_whole_api_in_every_phase(fuzz_stack: Stack) -> None:
    log = fuzz_stack.dir / "api.log"
    before = _statuses(log)
    report_dir = fuzz_stack.dir / "schemathesis"
    st_cli = Path(sys.executable).with_name("st")
    # One worker: CPython 3.11's AST constructor check misfires under threads ("recursion depth
    # mismatch") in hypothesis' code, and the run would report a runtime error of its own.
    command = [
        str(st_cli),
        "--config-file",
        str(CONFIG),
        "run",
        f"{fuzz_stack.url}/openapi.json",
        f"--phases={','.join(PHASES)}",
        "--checks=all",
        f"--max-examples={EXAMPLES}",
        "--seed=20261122",
        "--workers=1",
        "--request-timeout=60",
        "--generation-database=none",
        "--report=json,junit",
        f"--report-dir={report_dir}",
        "--no-color",
    ]
    run = subprocess.run(command, cwd=fuzz_stack.dir, capture_output=True, text=True, timeout=900)
    (fuzz_stack.dir / "schemathesis.out").write_text(run.stdout + run.stderr)
    report = json.loads(next(report_dir.glob("json-*.json")).read_text())
    statuses = _statuses(log) - before
    total = sum(statuses.values())
    summary = {
        "requests": total,
        "statuses": dict(sorted(statuses.items())),
        "test_cases": report["test_cases"],
        "operations": report["operations"]["tested"],
        "phases": {name: report["phases"][name]["status"] for name in PHASES},
        "failures": len(report["failures"]),
        "errors": len(report["errors"]),
        "elapsed_s": round(report["running_time"], 1),
    }
    text = json.dumps(summary, indent=2)
    (ROOT / "var").mkdir(exist_ok=True)
    (ROOT / "var" / "fuzz-report.json").write_text(text)  # the latest run's figures (var/ is not in git)
    print(f"\nschemathesis, every phase and check: {text}")
    tail = "\n".join((run.stdout + run.stderr).splitlines()[-120:])
    assert run.returncode == 0, tail
    assert all(status == "success" for status in summary["phases"].values()), tail
    assert not report["failures"] and not report["errors"] and report["test_cases"]["with_failures"] == 0, tail
    config = tomllib.loads(CONFIG.read_text())
    disabled = sum(1 for op in config.get("operations", []) if op.get("enabled") is False)
    assert report["operations"]["tested"] + disabled == report["operations"]["total"] >= 20
    assert not [code for code in statuses if code >= 500], text
    assert total >= MIN_REQUESTS, text
    with httpx.Client(base_url=fuzz_stack.url) as c:  # the server is still healthy afterwards
        assert c.get("/healthz").status_code == 200


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
