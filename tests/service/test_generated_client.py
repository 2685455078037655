"""Generated clients run the whole flow over real HTTP against a live stack.

Python: openapi-python-client (pinned in the test extras) generates a client from the live
``/openapi.json`` with no warning; the flow (robot, preset, plan, figures, tuning job, events,
deletion) goes through its typed models with a plain ``Client`` (keys are off).

TypeScript: openapi-typescript makes types of the same document, ``tests/ts/flow.ts`` (calls
through openapi-fetch) is compiled with ``tsc --strict`` against them and run with node. The
packages are pinned by ``tests/ts/package-lock.json`` and installed by ``tests/ts/setup.sh``."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from tests.service.conftest import ROOT, Stack, job_body

PYTHON_CONFIG = Path(__file__).with_name("openapi-python-client.yaml")
TS_DIR = ROOT / "tests" / "ts"
BIN = Path(sys.executable).parent


def _generator() -> str:
    exe = BIN / "openapi-python-client"
    if exe.exists():
        return str(exe)
    found = shutil.which("openapi-python-client")
    if found is None:
        pytest.skip("openapi-python-client is not installed (pip install -e '.[test]')")
    return found


@pytest.fixture
def spacearm_client(stack: Stack, tmp_path: Path) -> Iterator[ModuleType]:
    """The package openapi-python-client generates from the live document (asserted warning free)."""
    with stack.client() as c:
        (tmp_path / "openapi.json").write_text(json.dumps(c.get("/openapi.json").json()))
    out = tmp_path / "spacearm_client"
    # the generator formats its output with ruff (a post hook): on PATH from this environment
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    run = subprocess.run(
        [_generator(), "generate", "--path", str(tmp_path / "openapi.json"), "--output-path", str(out), "--meta", "none"]
        + ["--config", str(PYTHON_CONFIG)],
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
    )
    output = run.stdout + run.stderr
    assert run.returncode == 0, output
    assert "warning" not in output.lower() and "error" not in output.lower(), output
    sys.path.insert(0, str(tmp_path))
    try:
        yield importlib.import_module("spacearm_client")
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m == "spacearm_client" or m.startswith("spacearm_client.")]:
            del sys.modules[name]


def _op(tag: str, operation: str) -> Any:
    return importlib.import_module(f"spacearm_client.api.{tag}.{operation}")


def test_generated_python_client_runs_the_whole_flow(stack: Stack, spacearm_client: ModuleType) -> None:
    m = importlib.import_module("spacearm_client.models")
    types = importlib.import_module("spacearm_client.types")
    api = spacearm_client.Client(base_url=stack.url, timeout=None, raise_on_unexpected_status=True)

    # a robot: the paper's, read back through the typed RobotParams and stored again as a new one
    table1 = _op("robots", "get_robot").sync(robot_id="table1", client=api)
    assert isinstance(table1, m.RobotOut) and isinstance(table1.parameters, m.RobotParams), table1
    assert table1.preset is True and table1.n_joints == len(table1.parameters.links) == 6
    table1.parameters.name = "client copy"
    created_robot = _op("robots", "create_robot").sync_detailed(client=api, body=table1.parameters)
    robot = created_robot.parsed
    assert created_robot.status_code == 201 and isinstance(robot, m.RobotOut), created_robot.content
    assert created_robot.headers["location"] == f"/v1/robots/{robot.id}"
    assert robot.preset is False and robot.parameters.links[2].mass == table1.parameters.links[2].mass
    assert [(j.type_, j.unit) for j in robot.joints] == [(m.JointType.REVOLUTE, m.JointUnit.DEG)] * 6
    # the same robot through its URDF (text), stored again from it
    urdf = _op("robots", "get_robot_urdf").sync(robot_id=robot.id, client=api)
    assert isinstance(urdf, str) and urdf.lstrip().startswith("<")
    from_urdf = _op("robots", "create_robot").sync(client=api, body=m.RobotUrdfIn(urdf=urdf, name="from urdf"))
    assert isinstance(from_urdf, m.RobotOut) and from_urdf.n_joints == 6, from_urdf
    assert _op("robots", "delete_robot").sync_detailed(robot_id=from_urdf.id, client=api).status_code == 204

    # the paper's task (a preset), planned with typed method parameters
    preset = _op("tasks", "get_task_preset").sync(name="paper-line", client=api)
    assert isinstance(preset, m.TaskPreset) and isinstance(preset.task, m.TaskIn)
    method = m.MethodIn(name=m.MethodName.ADAPTIVE, params=m.MethodParams(lambda_max=0.06, epsilon=0.12))
    body = m.PlanRequestStoredRobot(
        robot_id=robot.id, task=preset.task, method=method, aggregation=m.AggregationName.MAX, replay=False
    )
    created = _op("plans", "create_plan").sync_detailed(client=api, body=body)
    plan = created.parsed
    assert created.status_code == 201 and isinstance(plan, m.PlanOut), created.content
    assert created.headers["location"] == f"/v1/plans/{plan.id}"
    assert plan.method.name is m.MethodName.ADAPTIVE and plan.method.params.lambda_max == 0.06
    assert isinstance(plan.method.params.epsilon, float) and isinstance(plan.metrics, m.PlanMetrics)
    assert plan.success and plan.metrics.joint_speed_limit_respected
    assert plan.metrics.attitude_term is m.AttitudeTermName.EQ18
    assert 0 < plan.metrics.max_joint_speed_deg_s <= 6.0
    assert isinstance(plan.trajectory, m.Trajectory) and len(plan.trajectory.t_s) == 61

    summary = _op("plans", "get_plan").sync(plan_id=plan.id, client=api, fields="")
    assert isinstance(summary, m.PlanOut) and summary.id == plan.id
    assert isinstance(summary.trajectory, types.Unset) and summary.metrics.objective_b == plan.metrics.objective_b
    # what it was asked (typed), the list filtered, the plan again with changes
    assert isinstance(plan.request, m.PlanRequestStoredRobot) and plan.request.method.name is m.MethodName.ADAPTIVE
    listed = _op("plans", "list_plans").sync(client=api, method=m.MethodName.ADAPTIVE, path_type=m.PathType.LINE, success=True)
    assert isinstance(listed, m.PlanList) and plan.id in [p.id for p in listed.items]
    rerun_body = m.PlanRerun.from_dict({"from_plan_id": plan.id, "method": {"name": "dls"}, "replay": False})
    rerun = _op("plans", "create_plan").sync(client=api, body=rerun_body, fields="")
    assert isinstance(rerun, m.PlanOut) and rerun.method.name is m.MethodName.DLS, rerun
    # the trajectory in every format as bytes (a File); the ROS message read by its typed model
    export = _op("plans", "get_plan_trajectory")
    csv_file = export.sync(plan_id=plan.id, client=api, format_=m.TrajectoryFormat.CSV)
    csv_text = csv_file.payload.read().decode()
    assert csv_text.startswith("t_s,") and len(csv_text.strip().splitlines()) == 62  # a header and 61 samples
    mat = export.sync(plan_id=plan.id, client=api, format_=m.TrajectoryFormat.MAT)
    assert isinstance(mat, types.File) and mat.payload.read()[:6] == b"MATLAB"
    ros_file = export.sync(plan_id=plan.id, client=api, format_=m.TrajectoryFormat.ROS)
    ros = m.RosJointTrajectory.from_dict(json.loads(ros_file.payload.read()))
    assert len(ros.points) == 61 and ros.points[-1].time_from_start.sec == 15 and len(ros.joint_names) == 6

    # figures as bytes, typed: SVG and PNG
    figure = _op("figures", "get_plan_figure")
    svg = figure.sync(plan_id=plan.id, name=m.GetPlanFigureName.JOINT_ANGLES, client=api)
    png = figure.sync(plan_id=plan.id, name=m.GetPlanFigureName.JOINT_ANGLES, client=api, format_=m.FigureFormat.PNG)
    pdf = figure.sync(plan_id=plan.id, name=m.GetPlanFigureName.JOINT_ANGLES, client=api, format_=m.FigureFormat.PDF, dpi=200)
    assert isinstance(pdf, types.File) and pdf.payload.read()[:5] == b"%PDF-"
    assert isinstance(svg, types.File) and b"<svg" in svg.payload.read()[:1000]
    assert isinstance(png, types.File) and png.payload.read()[:8] == b"\x89PNG\r\n\x1a\n"

    # a small tuning job, polled to the end; its result, events and convergence figure
    job_request = m.TuningJobRequestStoredRobot.from_dict({**job_body(), "robot_id": robot.id})
    submitted = _op("tuning", "create_tuning_job").sync_detailed(client=api, body=job_request)
    job = submitted.parsed
    assert submitted.status_code == 202 and isinstance(job, m.TuningJobOut), submitted.content
    assert submitted.headers["location"] == job.links.self_ == f"/v1/tuning-jobs/{job.id}"
    assert job.method is m.TunableMethodName.ADAPTIVE
    finished = (m.JobStatus.SUCCEEDED, m.JobStatus.FAILED, m.JobStatus.CANCELLED)
    deadline = time.monotonic() + 120
    while job.status not in finished and time.monotonic() < deadline:
        time.sleep(0.1)
        job = _op("tuning", "get_tuning_job").sync(job_id=job.id, client=api)
    assert job.status is m.JobStatus.SUCCEEDED, job
    assert job.progress.phase is m.PhaseName.DONE and isinstance(job.worker_id, str)
    assert [(p.name, p.role, p.completed) for p in job.progress.phases] == [
        (m.TunableMethodName.ADAPTIVE, m.PhaseRole.TUNED, 2),
        (m.TunableMethodName.DLS, m.PhaseRole.DLS_BASELINE, 2),
    ]
    result = _op("tuning", "get_tuning_job_result").sync(job_id=job.id, client=api)
    assert isinstance(result, m.TuningJobResult) and result.status is m.ResultStatus.SUCCEEDED, result
    assert isinstance(result.best_params, m.MethodParams) and result.best_params.lambda_max > 0
    assert isinstance(result.best_params.nu, types.Unset)  # adaptive's parameters only
    assert result.best_objective_b > 0 and len(result.history) == 3
    assert isinstance(result.dls_baseline, m.DLSBaseline) and result.dls_baseline.lambda_ > 0
    events = _op("tuning", "get_tuning_job_events").sync(job_id=job.id, client=api)
    assert isinstance(events, str) and events.count("event: generation") == 6 and "event: end" in events
    convergence = _op("figures", "get_tuning_job_figure").sync(
        job_id=job.id, name=m.GetTuningJobFigureName.CONVERGENCE, client=api, format_=m.FigureFormat.PNG
    )
    assert isinstance(convergence, types.File) and convergence.payload.read()[:4] == b"\x89PNG"

    # deletion; a missing plan is a typed Problem
    for tag, operation, key in (("plans", "delete_plan", "plan_id"), ("tuning", "delete_tuning_job", "job_id")):
        deleted = _op(tag, operation).sync_detailed(client=api, **{key: plan.id if tag == "plans" else job.id})
        assert deleted.status_code == 204, deleted.content
    assert _op("robots", "delete_robot").sync_detailed(robot_id=robot.id, client=api).status_code == 204
    lenient = spacearm_client.Client(base_url=stack.url, timeout=None)
    missing = _op("plans", "get_plan").sync(plan_id=plan.id, client=lenient)
    assert isinstance(missing, m.Problem) and missing.status == 404


def _setup_typescript() -> None:
    """``tests/ts/setup.sh``: node and npm (apt-get if missing), then ``npm ci`` of the lockfile."""
    run = subprocess.run(["sh", str(TS_DIR / "setup.sh")], capture_output=True, text=True, timeout=600)
    if run.returncode != 0:
        pytest.fail("tests/ts/setup.sh failed:\n" + run.stdout + run.stderr)


def _npx(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    tool = TS_DIR / "node_modules" / ".bin" / args[0]
    return subprocess.run([str(tool), *args[1:]], cwd=TS_DIR, capture_output=True, text=True, timeout=timeout)


def test_typescript_client_type_checks_and_runs_the_whole_flow(stack: Stack) -> None:
    _setup_typescript()
    generated = TS_DIR / "generated" / "spacearm.ts"
    generated.parent.mkdir(exist_ok=True)
    types_run = _npx("openapi-typescript", f"{stack.url}/openapi.json", "--output", str(generated))
    assert types_run.returncode == 0, types_run.stdout + types_run.stderr
    assert "warn" not in types_run.stderr.lower(), types_run.stderr
    compiled = _npx("tsc", "--project", "tsconfig.json", "--strict")
    assert compiled.returncode == 0, compiled.stdout + compiled.stderr
    flow = subprocess.run(
        ["node", str(TS_DIR / "build" / "flow.js"), stack.url], cwd=TS_DIR, capture_output=True, text=True, timeout=300
    )
    assert flow.returncode == 0, flow.stdout + flow.stderr
    out = json.loads(flow.stdout)
    assert out["type_checks"] == 24
    assert out["robot_status"] == 201 and out["robot_location"] == f"/v1/robots/{out['robot_id']}"
    assert out["robot_links"] == 6 and out["task_dt_s"] == 0.25
    assert out["robot_joint_types"] == ["revolute"] * 6 and out["urdf_robot_joints"] == 6
    assert out["plan_status"] == 201 and out["plan_location"] == f"/v1/plans/{out['plan_id']}"
    assert out["plan_method"] == "adaptive" and out["plan_params"] == {"lambda_max": 0.06, "epsilon": 0.12}
    assert out["plan_success"] is True and out["attitude_term"] == "eq18" and 0 < out["max_joint_speed_deg_s"] <= 6.0
    assert out["has_trajectory"] is False and out["replay_success"] is True
    assert out["read_back_id"] == out["plan_id"] and "trajectory" not in out["read_back_keys"]
    assert out["asked_method"] == "adaptive" and out["listed_has_plan"] is True
    assert out["rerun_method"] == "dls" and out["rerun_asked_method"] == {"name": "dls", "params": {}}
    assert out["csv_rows"] == 62 and out["ros_joints"] == 6 and out["ros_points"] == 61  # a header and 61 samples
    assert out["job_worker"] and out["result_status"] == "succeeded"
    assert out["plan_svg"] == {"kind": "svg", "type": "image/svg+xml"}
    assert out["plan_png"] == {"kind": "png", "type": "image/png"}
    assert out["job_status"] == "succeeded" and out["job_location"] == out["job_links_self"] == f"/v1/tuning-jobs/{out['job_id']}"
    assert out["phases"] == [["adaptive", "tuned", 2], ["dls", "dls_baseline", 2]]
    assert set(out["best_params"]) == {"lambda_max", "epsilon"} and out["history_length"] == 3
    assert out["best_objective_b"] > 0 and out["dls_lambda"] > 0
    assert out["event_kinds"] == ["status"] + ["generation"] * 6 + ["end"]  # a finished job's stream
    assert out["job_figure"] == {"kind": "png", "type": "image/png"}
    assert out["deleted"] == [204, 204, 204]
    assert out["missing_status"] == out["missing_problem_status"] == 404
