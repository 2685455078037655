"""Generate a Python client from the OpenAPI document with openapi-python-client and run a full
flow through it: create a plan, submit a small tuning job, poll it to completion, read the result."""

from __future__ import annotations

import importlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.service.conftest import PAPER_TASK, Stack, job_body


def _generator() -> str:
    exe = Path(sys.executable).parent / "openapi-python-client"
    if exe.exists():
        return str(exe)
    found = shutil.which("openapi-python-client")
    if found is None:
        pytest.skip("openapi-python-client is not installed (pip install openapi-python-client)")
    return found


def test_generated_client_full_flow(stack: Stack, tmp_path: Path) -> None:
    generator = _generator()
    with stack.client() as c:
        (tmp_path / "openapi.json").write_text(json.dumps(c.get("/openapi.json").json()))
    out = tmp_path / "spacearm_client"
    run = subprocess.run(
        [generator, "generate", "--path", str(tmp_path / "openapi.json"), "--output-path", str(out), "--meta", "none"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    sys.path.insert(0, str(tmp_path))
    try:
        client_mod = importlib.import_module("spacearm_client")
        models = importlib.import_module("spacearm_client.models")
        create_plan = importlib.import_module("spacearm_client.api.plans.create_plan")
        get_plan = importlib.import_module("spacearm_client.api.plans.get_plan")
        create_job = importlib.import_module("spacearm_client.api.tuning.create_tuning_job")
        get_job = importlib.import_module("spacearm_client.api.tuning.get_tuning_job")
        get_result = importlib.import_module("spacearm_client.api.tuning.get_tuning_job_result")

        api = client_mod.Client(base_url=stack.url, timeout=None)
        plan_request = models.PlanRequestStoredRobot.from_dict(
            {
                "robot_id": "table1",
                "task": PAPER_TASK,
                "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
            }
        )
        plan = create_plan.sync(client=api, body=plan_request)
        assert isinstance(plan, models.PlanOut), plan
        assert plan.metrics.joint_speed_limit_respected
        again = get_plan.sync(plan_id=plan.id, client=api)
        assert again.id == plan.id
        missing = get_plan.sync_detailed(plan_id="nope", client=api)
        assert missing.status_code == 404

        job = create_job.sync(client=api, body=models.TuningJobRequestStoredRobot.from_dict(job_body()))
        assert isinstance(job, models.TuningJobOut), job
        deadline = time.monotonic() + 60
        while True:
            current = get_job.sync(job_id=job.id, client=api)
            if str(current.status) in ("succeeded", "failed", "cancelled") or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert str(current.status) == "succeeded"
        result = get_result.sync(job_id=job.id, client=api)
        assert isinstance(result, models.TuningJobResult), result
        assert result.best_objective_b > 0
        assert len(result.history) == 3
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m == "spacearm_client" or m.startswith("spacearm_client.")]:
            del sys.modules[name]
