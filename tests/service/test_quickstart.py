"""The README's quick start, run as written against a live API and worker: its shell blocks in
one ``bash -euo pipefail`` (``$SPACEARM_URL`` pointed at the test stack, in a folder holding a copy
of ``examples/``), then what they made checked over HTTP: the paper's damping fails the plan,
the tuning job reproduces the paper's improvement over DLS (the paper's objective, eq. 18 as
printed, is the default), the plan re-run with the tuned parameters succeeds, its CSV and PNG are
the API's, and ``spacearm plan`` printed its table."""

from __future__ import annotations

import os
import re
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

import httpx

from service import figures
from tests.service.conftest import PAPER_TASK, ROOT, Stack

URL_LINE = "export SPACEARM_URL=http://127.0.0.1:8000"


def quick_start_script() -> str:
    """The shell blocks of the README's "Quick start" section (the ones that talk to the API)."""
    text = (ROOT / "README.md").read_text()
    section = re.search(r"^## Quick start\n(.*?)^## ", text, re.S | re.M)
    assert section is not None, "the README has no Quick start section"
    blocks = re.findall(r"```sh\n(.*?)```", section.group(1), re.S)
    assert blocks and blocks[0].count(URL_LINE) == 1
    lines = section.group(1).count("\n")
    print(f"\nquick start: {lines} lines, {len(blocks)} shell blocks")
    return "\n".join(blocks)


def test_the_readme_quick_start_runs_as_written(stack: Stack, client: httpx.Client, tmp_path: Path) -> None:
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    script = quick_start_script().replace(URL_LINE, f"export SPACEARM_URL={stack.url}")
    script += '\necho "IDS $PLAN_ID $JOB_ID $TUNED_ID"\n'
    env = {
        **os.environ,
        # `spacearm` of this environment, running this checkout's code
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
        "PYTHONPATH": str(ROOT),
    }
    started = time.perf_counter()
    done = subprocess.run(
        ["bash", "-euo", "pipefail", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    print(f"ran in {time.perf_counter() - started:.1f} s\n{done.stdout}{done.stderr}")
    assert done.returncode == 0, done.stderr
    ids = re.search(r"^IDS ([0-9a-f]{32}) ([0-9a-f]{32}) ([0-9a-f]{32})$", done.stdout, re.M)
    assert ids is not None, done.stdout
    plan_id, job_id, tuned_id = ids.groups()

    paper = client.get(f"/v1/plans/{plan_id}", params={"fields": ""}).json()
    assert paper["success"] is False and f"False {paper['message']}" in done.stderr

    result = client.get(f"/v1/tuning-jobs/{job_id}/result").json()
    print(
        f"quick start tuning job: adaptive B {result['best_objective_b']:.5f} {result['best_params']}, "
        f"DLS B {result['dls_baseline']['objective_b']:.5f}, improvement {result['improvement_over_dls_percent']:.1f} %"
    )
    assert result["status"] == "succeeded"
    assert all(m["attitude_term"] == "eq18" for m in result["best_metrics"])
    assert 20.0 < result["improvement_over_dls_percent"] < 40.0
    job = client.get(f"/v1/tuning-jobs/{job_id}").json()
    records = sum(len(phase["history"]) for phase in job["progress"]["phases"])  # generations 0 to N of each GA
    assert f"\n{records}\n" in f"\n{done.stdout}"  # the event stream had them all

    tuned = client.get(f"/v1/plans/{tuned_id}", params={"fields": ""}).json()
    assert tuned["success"] is True
    assert tuned["request"]["method"]["params"] == result["best_params"]
    assert {k: v for k, v in tuned["request"].items() if k != "method"} == {
        k: v for k, v in paper["request"].items() if k != "method"
    }
    csv = client.get(f"/v1/plans/{tuned_id}/trajectory", params={"format": "csv"}).content
    assert (tmp_path / "tuned.csv").read_bytes() == csv
    png = (tmp_path / "tuned-speeds.png").read_bytes()
    size_200_dpi = tuple(round(200 * inch) for inch in figures.FIGSIZE)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and struct.unpack(">II", png[16:24]) == size_200_dpi

    assert f"FAILED: {paper['message']}" in done.stdout  # spacearm plan, without the server
    # a plan posted without an objective gets the paper's default too
    plan = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": PAPER_TASK}).json()
    assert plan["metrics"]["attitude_term"] == "eq18"
