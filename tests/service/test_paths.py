"""Path types over real HTTP: the inspection presets plan successfully with their stated method
and the replay agrees; the shortest-duration endpoint; the 3D figure; tuning over the passes of
a scan with a real worker; 422s naming the field; an unreachable path as a failed plan saying
where it failed."""

from __future__ import annotations

import copy
import json
import sqlite3
from typing import Any

import httpx
import pytest

from tests.service.conftest import PAPER_TASK, Stack, wait_status

Q0 = PAPER_TASK["q0_deg"]
START_QUATERNION = [0.0, -0.087155743, -0.996194698, 0.0]
RASTER = {
    "type": "raster",
    "corner_m": [1.35, -0.15, 0.0],
    "scan_edge_m": [0.2, 0.0, 0.0],
    "step_edge_m": [0.0, 0.3, 0.0],
    "line_spacing_m": 0.05,
    "standoff_m": 0.15,
    "scan_speed_m_s": 0.02,
}
WAYPOINTS = {
    "type": "waypoints",
    "waypoints": [
        {"position_m": [1.30, 0.10, 0.45], "attitude_quaternion": START_QUATERNION},
        {"position_m": [1.50, -0.10, 0.30], "attitude_quaternion": START_QUATERNION},
    ],
}


def preset_body(client: httpx.Client, name: str, **changes: Any) -> dict[str, Any]:
    preset = client.get(f"/v1/task-presets/{name}").json()
    return {"robot_id": preset["robot_id"], "task": preset["task"], "method": preset["method"], **changes}


def test_presets_list_the_inspection_paths(client: httpx.Client) -> None:
    items = {p["name"]: p for p in client.get("/v1/task-presets").json()["items"]}
    assert {"paper-line", "raster-patch", "waypoint-inspection"} <= set(items)
    assert items["raster-patch"]["task"]["path"]["type"] == "raster"
    assert items["waypoint-inspection"]["task"]["path"]["type"] == "waypoints"
    for name in ("raster-patch", "waypoint-inspection"):
        method = items[name]["method"]
        assert method["name"] == "adaptive" and set(method["params"]) == {"lambda_max", "epsilon"}
    line = items["paper-line"]["task"]
    assert line["path"] == {"type": "line"} and line["duration_s"] == 15.0
    assert {k: line[k] for k in PAPER_TASK} == PAPER_TASK


@pytest.mark.parametrize("name", ["raster-patch", "waypoint-inspection"])
def test_inspection_presets_plan_with_their_method_and_the_replay_agrees(client: httpx.Client, name: str) -> None:
    r = client.post("/v1/plans", params={"fields": "replay"}, json=preset_body(client, name, replay=True))
    assert r.status_code == 201, r.text
    plan = r.json()
    assert plan["success"] is True and plan["message"] == "ok"
    assert plan["metrics"]["max_joint_speed_deg_s"] <= 6.0
    replay = plan["replay"]
    assert replay["success"] is True
    assert replay["plan_gap_position_max_m"] < 1e-6 and replay["plan_gap_attitude_max_rad"] < 1e-6
    assert replay["path_position_error_max_m"] == pytest.approx(plan["metrics"]["position_error_max_m"], abs=1e-6)
    # the plain inverse cannot: the paths pass near the GJM's singularity
    plain = client.post("/v1/plans", params={"fields": ""}, json=preset_body(client, name, method={"name": "inverse"}))
    assert plain.status_code == 201 and plain.json()["success"] is False
    assert "joint speed limit broken" in plain.json()["message"] and "first failed at t = " in plain.json()["message"]


def test_scene_3d_figure(client: httpx.Client) -> None:
    from tests.service.test_figures import assert_png, assert_svg, svg_text

    body = preset_body(client, "waypoint-inspection")
    stored = client.post("/v1/plans", params={"fields": ""}, json=body).json()["id"]
    robot = client.get("/v1/robots/table1").json()["parameters"]
    inline_body = {key: value for key, value in body.items() if key != "robot_id"}
    inline = client.post(
        "/v1/plans", params={"fields": ""}, json={**inline_body, "robot": robot, "task": {**body["task"], "dt_s": 0.5}}
    ).json()["id"]
    for plan_id in (stored, inline):
        text = svg_text(assert_svg(client.get(f"/v1/plans/{plan_id}/figures/scene-3d")))
        for label in ("x [m]", "y [m]", "z [m]", "desired end-effector path", "achieved end-effector path", "carrier CoM drift"):
            assert label in text
        assert text.count("arm at t = ") == 5
        assert_png(client.get(f"/v1/plans/{plan_id}/figures/scene-3d", params={"format": "png"}))
    page = client.get(f"/plans/{stored}").text
    assert f"/v1/plans/{stored}/figures/scene-3d" in page


def test_shortest_duration(client: httpx.Client, stack: Stack) -> None:
    body = preset_body(client, "waypoint-inspection", replay=False, search={"relative_tolerance": 0.002, "candidates": 3})
    r = client.post("/v1/plans/shortest-duration", json=body)
    assert r.status_code == 201, r.text
    found = r.json()
    search, plan = found["search"], found["plan"]
    assert search["success"] is True and plan["success"] is True
    assert r.headers["location"] == f"/v1/plans/{plan['id']}"
    assert 0.0 < search["relative_gap"] <= 0.002
    assert search["infeasible_duration_s"] < search["duration_s"]
    assert search["joint_speed_margin_deg_s"] >= 0.0 and "joint speed limit broken" in search["limiting"]
    assert len(plan["trajectory"]["t_s"]) == int(-(-search["duration_s"] // 0.25)) + 1
    assert client.get(r.headers["location"], params={"fields": ""}).json()["success"] is True
    # the stored request carries the duration found: planning it again gives the same plan
    with sqlite3.connect(stack.db_path) as db:
        (request,) = db.execute("select request from plans where id = ?", (plan["id"],)).fetchone()
    stored = json.loads(request)
    assert stored["task"]["duration_s"] == search["duration_s"] and "search" not in stored
    again = client.post("/v1/plans", params={"fields": ""}, json=stored).json()
    assert again["metrics"] == plan["metrics"]
    # the boundary within 1%: 1% faster fails, 1% slower succeeds
    for factor, success in ((0.99, False), (1.01, True)):
        task = {**stored["task"], "duration_s": factor * search["duration_s"]}
        result = client.post("/v1/plans", params={"fields": ""}, json={**stored, "task": task}).json()
        assert result["success"] is success, (factor, result["message"])


def test_shortest_duration_without_a_feasible_one(client: httpx.Client) -> None:
    body = {
        "robot_id": "table1",
        "task": PAPER_TASK,
        "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
        "search": {"max_duration_s": 4.0},
    }
    r = client.post("/v1/plans/shortest-duration", params={"fields": ""}, json=body)
    assert r.status_code == 201, r.text
    assert r.json()["search"]["success"] is False and r.json()["plan"]["success"] is False
    assert "no feasible duration up to 4 s" in r.json()["search"]["message"]
    for search, field in (
        ({"max_duration_s": 0.1}, "body.search.max_duration_s"),
        ({"relative_tolerance": 0.05}, "body.search.relative_tolerance"),
        ({"candidates": 0}, "body.search.candidates"),
    ):
        bad = client.post("/v1/plans/shortest-duration", json={**body, "search": search})
        assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == field, bad.text


def test_tuning_over_the_passes_of_a_scan(client: httpx.Client) -> None:
    """A robust tuning job whose tasks are the passes of the raster preset (worker process)."""
    raster = client.get("/v1/task-presets/raster-patch").json()["task"]
    tasks = [{**raster, "path": {**raster["path"], "pass_index": i}} for i in range(7)]
    body = {
        "robot_id": "table1",
        "tasks": tasks,
        "method": "adaptive",
        "ga": {"population": 4, "generations": 1, "seed": 2},
        "objective": {"task_aggregation": "max"},
        "compare_with_dls": False,
    }
    r = client.post("/v1/tuning-jobs", json=body)
    assert r.status_code == 202, r.text
    job = wait_status(client, r.json()["id"], ("succeeded", "failed"), timeout=120)
    assert job["status"] == "succeeded", job
    result = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
    assert len(result["best_metrics"]) == 7
    assert result["best_objective_b"] == max(m["objective_b"] for m in result["best_metrics"])


def test_an_unreachable_path_is_a_failed_plan_saying_where(client: httpx.Client) -> None:
    task = {"q0_deg": Q0, "path": {**RASTER, "corner_m": [2.6, -0.15, 0.0], "line_spacing_m": 0.1}}
    r = client.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": task, "method": {"name": "dls"}})
    assert r.status_code == 201, r.text
    plan = r.json()
    assert plan["success"] is False
    assert "first failed at t = " in plan["message"] and "desired pose: position [" in plan["message"]


def _with(task: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """``task`` with the value at a dotted ``path`` (``path.waypoints.0.position_m``) set."""
    out = copy.deepcopy(task)
    *parents, last = path.split(".")
    node: Any = out
    for key in parents:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return out


RASTER_TASK = {"q0_deg": Q0, "path": RASTER}
WAYPOINT_TASK = {"q0_deg": Q0, "path": WAYPOINTS}
ARC_TASK = {"q0_deg": Q0, "path": {"type": "arc", "centre_m": [1.30, -0.05, 0.5], "axis": [0, 0, 1], "angle_deg": 90}}


@pytest.mark.parametrize(
    ("task", "change", "value", "field"),
    [
        (WAYPOINT_TASK, "path.waypoints", [WAYPOINTS["waypoints"][0]] * 101, "body.task.path.waypoints.waypoints"),
        (WAYPOINT_TASK, "path.waypoints", [], "body.task.path.waypoints.waypoints"),
        (WAYPOINT_TASK, "path.waypoints.1", WAYPOINTS["waypoints"][0], "body.task.path.waypoints.waypoints[1]"),
        (
            WAYPOINT_TASK,
            "path.waypoints.0.attitude_quaternion",
            [0.0, -0.1, -0.996194698, 0.0],
            "body.task.path.waypoints.waypoints[0].attitude_quaternion",
        ),
        (
            WAYPOINT_TASK,
            "path.waypoints.1.attitude_quaternion",
            [0, 0, 0, 0],
            "body.task.path.waypoints.waypoints[1].attitude_quaternion",
        ),
        (WAYPOINT_TASK, "path.max_speed_m_s", 0.0, "body.task.path.waypoints.max_speed_m_s"),
        (WAYPOINT_TASK, "path.max_angular_acceleration_deg_s2", -1.0, "body.task.path.waypoints.max_angular_acceleration_deg_s2"),
        (WAYPOINT_TASK, "path.segment_durations_s", [10.0], "body.task.path.waypoints.segment_durations_s"),
        (WAYPOINT_TASK, "target_position_m", [1.5, 0.0, -0.2], "body.task.target_position_m"),
        (RASTER_TASK, "path.line_spacing_m", 0.31, "body.task.path.raster.line_spacing_m"),
        (RASTER_TASK, "path.line_spacing_m", 1e-4, "body.task.path.raster.line_spacing_m"),
        (RASTER_TASK, "path.standoff_m", 0.0, "body.task.path.raster.standoff_m"),
        (RASTER_TASK, "path.scan_speed_m_s", -0.01, "body.task.path.raster.scan_speed_m_s"),
        (RASTER_TASK, "path.scan_acceleration_m_s2", 0.0, "body.task.path.raster.scan_acceleration_m_s2"),
        (RASTER_TASK, "path.turn_radius_m", 0.04, "body.task.path.raster.turn_radius_m"),
        (RASTER_TASK, "path.step_edge_m", [0.1, 0.3, 0.0], "body.task.path.raster.step_edge_m"),
        (RASTER_TASK, "path.pass_index", 7, "body.task.path.raster.pass_index"),
        (RASTER_TASK, "path.scan_speed_m_s", 1e-4, "body.task.path.raster"),
        (RASTER_TASK, "dt_s", 0.005, "body.task.dt_s"),
        (RASTER_TASK, "path.corner_m", [1e9, 0.0, 0.0], "body.task.path.raster.corner_m[0]"),
        (ARC_TASK, "path.axis", None, "body.task.path.arc.axis"),
        (ARC_TASK, "path.via_position_m", [1.4, 0.0, 0.6], "body.task.path.arc.centre_m"),
        (ARC_TASK, "path.angle_deg", 0.0, "body.task.path.arc.angle_deg"),
        (ARC_TASK, "path.type", "spiral", "body.task.path"),
        ({"q0_deg": Q0}, "path", {"type": "line"}, "body.task.target_position_m"),
    ],
)
def test_invalid_paths_are_422s_naming_the_field(
    client: httpx.Client, task: dict[str, Any], change: str, value: Any, field: str
) -> None:
    body = {"robot_id": "table1", "task": _with(task, change, value)}
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith("application/problem+json")
    assert r.json()["errors"][0]["field"] == field, r.json()


def test_every_preset_posts_back_as_it_is(client: httpx.Client) -> None:
    """Each preset's `robot_id`, `task` and `method`, posted as they come, plan (four had no
    method, and their null was a 422)."""
    items = client.get("/v1/task-presets").json()["items"]
    assert all(p["method"] is not None for p in items)
    for preset in items:
        r = client.post("/v1/plans", params={"fields": ""}, json=preset_body(client, preset["name"], replay=False))
        assert r.status_code == 201, (preset["name"], r.text)
        assert r.json()["method"]["name"] == preset["method"]["name"]
