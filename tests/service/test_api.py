"""Every endpoint over real HTTP against a uvicorn subprocess and a SQLite file."""

from __future__ import annotations

import copy
import math
import sqlite3
import threading
import time
from collections.abc import Callable

import httpx
import pytest

from tests.service.conftest import PAPER_TASK, Stack

PROBLEM = "application/problem+json"


def _problem(r: httpx.Response, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert {"type", "title", "status", "detail"} <= set(body)
    assert body["status"] == status
    return body


def plan_path(response: httpx.Response) -> str:
    return f"/v1/plans/{response.json()['id']}"


def test_health_and_ready(client: httpx.Client) -> None:
    assert client.get("/healthz").json()["status"] == "ok"
    ready = client.get("/readyz")
    assert ready.status_code == 200
    assert ready.json()["revision"] == ready.json()["head"] == "0007"
    assert ready.json()["kernels"] == "ok"


def test_robots_crud(client: httpx.Client) -> None:
    listing = client.get("/v1/robots", params={"limit": 10}).json()
    assert listing["total"] >= 1
    preset = client.get("/v1/robots/table1").json()
    assert preset["preset"] is True and preset["n_joints"] == 6
    # the answer itself posted back: one error that says to post its parameters
    answer = _problem(client.post("/v1/robots", json={**preset, "name": "my-arm"}), 422)
    assert len(answer["errors"]) == 1 and answer["errors"][0]["field"] == "body", answer
    assert "post the `parameters` object" in answer["detail"], answer
    params = copy.deepcopy(preset["parameters"])
    params["name"] = "my-arm"
    params["base"]["mass"] = 500.0
    r = client.post("/v1/robots", json=params)
    assert r.status_code == 201, r.text
    robot = r.json()
    assert r.headers["location"] == f"/v1/robots/{robot['id']}"
    assert client.get(r.headers["location"]).json()["parameters"]["base"]["mass"] == 500.0
    assert client.get("/v1/robots", params={"limit": 1, "offset": 0}).json()["items"][0]["id"] == "table1"
    assert client.delete(f"/v1/robots/{robot['id']}").status_code == 204
    _problem(client.get(f"/v1/robots/{robot['id']}"), 404)
    _problem(client.delete(f"/v1/robots/{robot['id']}"), 404)
    _problem(client.delete("/v1/robots/table1"), 409)
    assert client.get("/v1/robots/table1").status_code == 200


def test_a_plan_of_a_robot_deleted_elsewhere_is_a_404(client: httpx.Client, stack: Stack) -> None:
    """The API keeps the stored robots its plans read (robots never change); one deleted by another
    process since is still refused, by the plans' foreign key, with the same 404 as any missing robot."""
    params = {**client.get("/v1/robots/table1").json()["parameters"], "name": "deleted-elsewhere"}
    robot_id = client.post("/v1/robots", json=params).json()["id"]
    body = {"robot_id": robot_id, "task": PAPER_TASK, "replay": False}
    for _ in range(2):  # read, then kept
        assert client.post("/v1/plans", params={"fields": ""}, json=body).status_code == 201
    with sqlite3.connect(stack.db_path) as db:  # as another API process deletes it
        db.execute("PRAGMA foreign_keys=ON")
        db.execute("DELETE FROM robots WHERE id = ?", (robot_id,))
    gone = _problem(client.post("/v1/plans", json=body), 404)
    assert robot_id in gone["detail"]
    assert client.get("/v1/plans", params={"robot_id": robot_id}).json()["total"] == 0  # SET NULL, none stored since
    assert client.post("/v1/plans", params={"fields": ""}, json={**body, "robot_id": "table1"}).status_code == 201


def test_robot_validation_names_the_field(client: httpx.Client) -> None:
    params = copy.deepcopy(client.get("/v1/robots/table1").json()["parameters"])
    params["links"][2]["mass"] = -1.0
    body = _problem(client.post("/v1/robots", json=params), 422)
    assert body["errors"][0]["field"].startswith("body.links[2].mass"), body
    del params["base"]
    body = _problem(client.post("/v1/robots", json=params), 422)
    assert any(e["field"] == "body.base" for e in body["errors"]), body


def test_jacobian(client: httpx.Client) -> None:
    r = client.post("/v1/robots/table1/jacobian", json={"joint_angles_deg": PAPER_TASK["q0_deg"]})
    assert r.status_code == 200, r.text
    body = r.json()
    assert len(body["gjm"]) == 6 and len(body["gjm"][0]) == 6
    assert body["determinant"] is not None
    assert math.isclose(body["manipulability"], abs(body["determinant"]), rel_tol=1e-6)
    assert body["ee_position_m"] == pytest.approx([1.3717, -0.0763, 0.6415], abs=1e-3)
    assert len(body["ee_attitude_quaternion"]) == 4
    moved = client.post(
        "/v1/robots/table1/jacobian",
        json={
            "joint_angles_deg": PAPER_TASK["q0_deg"],
            "base_position_m": [1.0, 0.0, 0.0],
            "base_attitude_quaternion": [1.0, 0.0, 0.0, 0.0],
        },
    ).json()
    assert math.isclose(moved["ee_position_m"][0], body["ee_position_m"][0] + 1.0, abs_tol=1e-9)
    _problem(client.post("/v1/robots/table1/jacobian", json={"joint_angles_deg": [1, 2, 3]}), 422)
    _problem(client.post("/v1/robots/nope/jacobian", json={"joint_angles_deg": PAPER_TASK["q0_deg"]}), 404)


def test_task_presets(client: httpx.Client) -> None:
    listing = client.get("/v1/task-presets").json()
    assert "paper-line" in [p["name"] for p in listing["items"]]
    preset = client.get("/v1/task-presets/paper-line").json()
    # The paper's task, with the defaults of the fields other robots need shown.
    assert preset["task"] == {
        **PAPER_TASK,
        "path": {"type": "line"},
        "q0_m": None,
        "tracks": "pose",
        "joint_speed_limit_m_s": None,
        "clearance_m": 0.0,
        "scene": None,
    }
    _problem(client.get("/v1/task-presets/nope"), 404)


def test_plan_create_get_list(client: httpx.Client) -> None:
    body = {
        "robot_id": "table1",
        "task": PAPER_TASK,
        "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
        "feedback_gain": 0.0,
        "aggregation": "max",
        "weights": [0.5, 0.5],
        "replay": True,
    }
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 201, r.text
    plan = r.json()
    assert r.headers["location"] == f"/v1/plans/{plan['id']}"
    assert plan["robot_id"] == "table1" and plan["method"]["name"] == "adaptive"
    m = plan["metrics"]
    assert m["joint_speed_limit_respected"] is True and m["objective_b"] > 0
    assert m["max_joint_speed_deg_s"] <= 6.0 + 1e-9
    assert m["min_abs_det_gjm"] is not None and m["time_of_min_abs_det_gjm_s"] is not None
    traj = plan["trajectory"]
    assert len(traj["t_s"]) == 61 and len(traj["joint_angles_deg"][0]) == 6
    assert traj["joint_angles_deg"][0] == pytest.approx(PAPER_TASK["q0_deg"], abs=1e-9)
    assert len(traj["ee_attitude_quaternion"][0]) == 4 and len(traj["base_attitude_quaternion"][0]) == 4
    assert plan["replay"]["plan_gap_position_max_m"] < 0.01
    assert plan["replay"]["angular_momentum_residual_max_n_m_s"] < 1e-6

    stored = client.get(f"/v1/plans/{plan['id']}").json()
    assert stored["metrics"] == m and stored["trajectory"]["t_s"] == traj["t_s"]
    listing = client.get("/v1/plans").json()
    assert listing["total"] >= 1
    assert plan["id"] in [p["id"] for p in listing["items"]]
    assert all("trajectory" not in p for p in listing["items"])
    unmatched = _problem(client.get("/v1/plans/nope"), 404)  # not an id: no route matches
    assert "nothing at /v1/plans/nope" in unmatched["detail"] and "32 lowercase hexadecimal" in unmatched["detail"]
    missing = _problem(client.get(f"/v1/plans/{'0' * 32}"), 404)  # an id no plan has
    assert "0" * 32 in missing["detail"] and "nothing at" not in missing["detail"]


def test_plan_variants_and_errors(client: httpx.Client) -> None:
    robot = client.get("/v1/robots/table1").json()["parameters"]
    inline = client.post("/v1/plans", json={"robot": robot, "task": PAPER_TASK, "method": {"name": "inverse"}, "replay": False})
    assert inline.status_code == 201, inline.text
    plain = inline.json()
    assert plain["robot_id"] is None and plain["replay"] is None
    # the plain inverse breaks the speed limit near the singularity: B is null
    assert plain["metrics"]["joint_speed_limit_respected"] is False
    assert plain["metrics"]["objective_b"] is None and plain["success"] is False

    _problem(client.post("/v1/plans", json={"robot_id": "nope", "task": PAPER_TASK}), 404)
    bad = _problem(client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "magic"}}), 422)
    assert bad["errors"][0]["field"] == "body.method.name"
    bad = _problem(
        client.post(
            "/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "dls", "params": {"lambda": -1}}}
        ),
        422,
    )
    assert "lambda" in bad["detail"]
    bad = _problem(client.post("/v1/plans", json={"robot_id": "table1", "task": {**PAPER_TASK, "q0_deg": [0, 0]}}), 422)
    assert bad["errors"][0]["field"] == "body.task.q0_deg"
    bad = _problem(client.post("/v1/plans", json={"robot_id": "table1", "task": {**PAPER_TASK, "ramp_time_s": 9.0}}), 422)
    assert bad["errors"][0]["field"] == "body.task.ramp_time_s"
    refused_by_the_engine = bad
    bad = _problem(client.post("/v1/plans", json={"robot_id": "table1", "task": {**PAPER_TASK, "profile": "cubic"}}), 422)
    assert bad["errors"][0]["field"] == "body.task.profile"
    no_robot = _problem(client.post("/v1/plans", json={"task": PAPER_TASK}), 422)
    no_sections = _problem(client.get(f"/v1/plans/{plain['id']}", params={"fields": "summary,nonsense"}), 422)
    no_ids = _problem(client.get("/v1/plans/compare/figures/tracking-errors", params={"ids": ","}), 422)
    no_format = _problem(client.post("/v1/meshes", content=b"solid x", headers={"content-type": "text/plain"}), 422)
    # the engine's refusal, the schema's and the service's own name the field alike: detail starts
    # with errors[].field
    for problem in (refused_by_the_engine, bad, no_robot, no_sections, no_ids, no_format):
        assert problem["detail"].startswith(problem["errors"][0]["field"] + ": "), problem
    assert [p["errors"][0]["field"] for p in (no_robot, no_sections, no_ids, no_format)] == [
        "body",
        "query.fields",
        "query.ids",
        "query.format",
    ]


def test_long_plan_does_not_block_other_requests(client: httpx.Client, stack: Stack) -> None:
    fine = {"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 0.01}, "replay": True}
    done = threading.Event()

    def long_plan() -> None:
        with stack.client() as c:
            assert c.post("/v1/plans", json=fine).status_code == 201
        done.set()

    t = threading.Thread(target=long_plan)
    start = time.monotonic()
    t.start()
    time.sleep(0.2)
    assert client.get("/healthz").status_code == 200
    quick = time.monotonic() - start
    t.join(60)
    assert done.is_set()
    assert quick < time.monotonic() - start  # health answered before the long plan finished


def test_openapi_contract(client: httpx.Client) -> None:
    doc = client.get("/openapi.json").json()
    ops = {op["operationId"]: (path, method, op) for path, item in doc["paths"].items() for method, op in item.items()}
    expected = {
        "list_robots": ("/v1/robots", "get", "robots"),
        "create_robot": ("/v1/robots", "post", "robots"),
        "get_robot": ("/v1/robots/{robot_id}", "get", "robots"),
        "delete_robot": ("/v1/robots/{robot_id}", "delete", "robots"),
        "compute_jacobian": ("/v1/robots/{robot_id}/jacobian", "post", "robots"),
        "list_task_presets": ("/v1/task-presets", "get", "tasks"),
        "get_task_preset": ("/v1/task-presets/{name}", "get", "tasks"),
        "create_plan": ("/v1/plans", "post", "plans"),
        "get_plan": ("/v1/plans/{plan_id}", "get", "plans"),
        "list_plans": ("/v1/plans", "get", "plans"),
        "create_tuning_job": ("/v1/tuning-jobs", "post", "tuning"),
        "list_tuning_jobs": ("/v1/tuning-jobs", "get", "tuning"),
        "get_tuning_job": ("/v1/tuning-jobs/{job_id}", "get", "tuning"),
        "get_tuning_job_result": ("/v1/tuning-jobs/{job_id}/result", "get", "tuning"),
        "cancel_tuning_job": ("/v1/tuning-jobs/{job_id}/cancel", "post", "tuning"),
    }
    for op_id, (path, method, tag) in expected.items():
        assert op_id in ops, op_id
        assert ops[op_id][:2] == (path, method)
        assert ops[op_id][2]["tags"] == [tag]
    assert "application/problem+json" in ops["get_plan"][2]["responses"]["404"]["content"]
    assert "409" in ops["get_tuning_job_result"][2]["responses"]
    assert doc["components"]["schemas"]["TaskIn"]["examples"][0]["q0_deg"] == PAPER_TASK["q0_deg"]


def test_plan_objective_attitude_term(client: httpx.Client) -> None:
    body = {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "dls", "params": {"lambda": 0.035}}, "replay": False}
    angle = client.post("/v1/plans", json={**body, "attitude_term": "angle"}).json()["metrics"]
    printed = client.post("/v1/plans", json=body).json()["metrics"]  # eq. 18 as printed: the default
    assert angle["attitude_term"] == "angle" and printed["attitude_term"] == "eq18"
    expected = 0.5 * printed["position_error_max_m"] + 0.5 * printed["coupled_error_max_m_rad"]
    assert printed["objective_b"] == pytest.approx(expected)
    assert 0.002 < printed["objective_b"] < angle["objective_b"]
    _problem(client.post("/v1/plans", json={**body, "attitude_term": "rpy"}), 422)


def test_a_20000_step_plan_is_replayed_and_fields_leave_the_trajectory_out(client: httpx.Client) -> None:
    """The longest plan the API accepts is replayed synchronously by default (the compiled
    replay takes about a second); ``fields=replay`` returns it without the trajectory."""
    task = {**PAPER_TASK, "duration_s": 500.0, "ramp_time_s": 50.0, "dt_s": 0.025}
    body = {"robot_id": "table1", "task": task, "method": {"name": "dls", "params": {"lambda": 0.05}}, "replay": True}
    r = client.post("/v1/plans", params={"fields": "replay"}, json=body)
    assert r.status_code == 201, r.text
    plan = r.json()
    assert "trajectory" not in plan and plan["replay"]["success"] is True
    assert plan["replay"]["plan_gap_position_max_m"] < 1e-6
    summary = client.get(plan_path(r), params={"fields": ""}).json()
    assert set(summary) == {
        *("id", "robot_id", "request", "method", "success", "message", "metrics", "robustness", "elapsed_s", "created_at")
    }
    full = client.get(plan_path(r)).json()
    assert len(full["trajectory"]["t_s"]) == 20001 and full["replay"] == plan["replay"]


def test_plans_longer_than_the_replay_limit_are_not_replayed(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.env["SPACEARM_MAX_REPLAY_STEPS"] = "100"
    stack.start_api()
    with stack.client() as c:
        body = {"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 0.125}, "method": {"name": "dls"}, "replay": True}
        r = c.post("/v1/plans", json=body)
        assert r.status_code == 201, r.text
        replay = r.json()["replay"]
        assert replay["success"] is False
        assert "120 steps" in replay["message"] and "SPACEARM_MAX_REPLAY_STEPS" in replay["message"]
        assert len(r.json()["trajectory"]["t_s"]) == 121


def test_plan_fields(client: httpx.Client) -> None:
    body = {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "adaptive"}, "replay": True}
    created = client.post("/v1/plans", json=body)
    assert created.status_code == 201 and created.headers["location"] == plan_path(created)
    full = created.json()
    assert set(full) >= {"id", "metrics", "trajectory", "replay"}
    # The stored trajectory comes back as stored (NaN as null), the same as the POST answered.
    assert client.get(plan_path(created)).json() == full
    assert "replay" not in client.get(plan_path(created), params={"fields": "trajectory"}).json()
    only_replay = client.get(plan_path(created), params={"fields": " replay ,"}).json()
    assert "trajectory" not in only_replay and only_replay["replay"] == full["replay"]
    body_422 = _problem(client.get(plan_path(created), params={"fields": "trajectory,joints"}), 422)
    assert body_422["errors"][0]["field"] == "query.fields" and "joints" in body_422["errors"][0]["message"]
    _problem(client.post("/v1/plans", params={"fields": "everything"}, json=body), 422)
