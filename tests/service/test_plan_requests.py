"""Plans say what they were asked, over real HTTP: `request` in every plan response and in the
list, the list's filters, re-running a stored plan with changes (`from_plan_id` and a JSON merge
patch); and ``spacearm plan FILE``, the same request planned without a server."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from tests.service.conftest import PAPER_TASK, ROOT

EXAMPLE = json.loads((ROOT / "examples" / "paper-plan.json").read_text())


def post(client: httpx.Client, body: dict[str, Any]) -> dict[str, Any]:
    r = client.post("/v1/plans", params={"fields": ""}, json=body)
    assert r.status_code == 201, r.text
    plan: dict[str, Any] = r.json()
    return plan


def preset(client: httpx.Client, name: str) -> dict[str, Any]:
    p = client.get(f"/v1/task-presets/{name}").json()
    return {"robot_id": p["robot_id"], "task": p["task"], "replay": False, **({"method": p["method"]} if p["method"] else {})}


@pytest.fixture(scope="module")
def stored(stack: Any) -> dict[str, dict[str, Any]]:
    """Plans of several robots, paths, methods and verdicts."""
    with stack.client() as c:
        return {
            "paper": post(c, {**EXAMPLE, "replay": False}),  # fails: breaks the speed limit
            "tuned": post(c, {**EXAMPLE, "method": {"name": "adaptive", "params": {"lambda_max": 0.04, "epsilon": 0.37}}}),
            "dls": post(c, {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "dls"}, "replay": False}),
            "raster": post(c, preset(c, "raster-patch")),
            "arm3": post(c, preset(c, "arm3-position")),
        }


def test_every_plan_response_says_what_it_was_asked(client: httpx.Client, stored: dict[str, Any]) -> None:
    paper = stored["paper"]
    asked = paper["request"]
    # the request as posted, every default filled in
    assert asked["robot_id"] == "table1" and "robot" not in asked
    assert asked["task"] == {**asked["task"], **EXAMPLE["task"]} and asked["task"]["path"] == {"type": "line"}
    assert asked["method"] == EXAMPLE["method"] and asked["replay"] is False and asked["secondary"] is None
    assert {k: asked[k] for k in ("feedback_gain", "aggregation", "weights", "attitude_term")} == {
        "feedback_gain": 0.0,
        "aggregation": "max",
        "weights": [0.5, 0.5],
        "attitude_term": "eq18",
    }
    assert client.get(f"/v1/plans/{paper['id']}", params={"fields": ""}).json()["request"] == asked
    listed = {p["id"]: p for p in client.get("/v1/plans", params={"limit": 500}).json()["items"]}
    assert all(listed[p["id"]]["request"] == p["request"] for p in stored.values())
    assert stored["raster"]["request"]["task"]["path"]["type"] == "raster"
    # posting the request again plans the same plan
    again = post(client, asked)
    assert again["request"] == asked and again["metrics"] == paper["metrics"]


def test_the_list_filters_by_robot_path_type_method_and_success(client: httpx.Client, stored: dict[str, Any]) -> None:
    everything = client.get("/v1/plans", params={"limit": 500}).json()["items"]
    assert {p["id"] for p in stored.values()} <= {p["id"] for p in everything}

    def ids(**query: Any) -> set[str]:
        page = client.get("/v1/plans", params={"limit": 500, **query}).json()
        assert page["total"] == len(page["items"])
        return {p["id"] for p in page["items"]}

    filters = {
        "robot_id": lambda p, v: p["robot_id"] == v,
        "path_type": lambda p, v: p["request"]["task"]["path"]["type"] == v,
        "method": lambda p, v: p["method"]["name"] == v,
        "success": lambda p, v: p["success"] == v,
    }
    cases = [
        {"robot_id": "arm3"},
        {"robot_id": "table1"},
        {"path_type": "raster"},
        {"path_type": "line"},
        {"method": "dls"},
        {"success": True},
        {"success": False},
        {"robot_id": "table1", "method": "adaptive", "success": True},
    ]
    for query in cases:
        expected = {p["id"] for p in everything if all(filters[k](p, v) for k, v in query.items())}
        assert expected and ids(**{k: str(v).lower() if isinstance(v, bool) else v for k, v in query.items()}) == expected, query
    assert ids(robot_id="arm3", path_type="raster") == set()
    assert stored["tuned"]["id"] in ids(success="true") and stored["paper"]["id"] in ids(success="false")
    for bad in ({"path_type": "spiral"}, {"method": "magic"}, {"success": "maybe"}):
        assert client.get("/v1/plans", params=bad).status_code == 422, bad


def test_a_stored_plan_runs_again_with_a_merge_patch(client: httpx.Client, stored: dict[str, Any]) -> None:
    paper = stored["paper"]
    # members merge: the method keeps its name, the task its other fields
    tuned = post(
        client,
        {"from_plan_id": paper["id"], "method": {"params": {"lambda_max": 0.04, "epsilon": 0.37}}, "task": {"duration_s": 20}},
    )
    assert tuned["request"]["method"] == {"name": "adaptive", "params": {"lambda_max": 0.04, "epsilon": 0.37}}
    assert tuned["request"]["task"] == {**paper["request"]["task"], "duration_s": 20.0}
    assert {k: v for k, v in tuned["request"].items() if k not in ("method", "task")} == {
        k: v for k, v in paper["request"].items() if k not in ("method", "task")
    }
    assert tuned["success"] and not paper["success"]
    # the same request posted whole plans the same plan
    assert post(client, tuned["request"])["metrics"] == tuned["metrics"]

    # another method's name replaces the method whole (adaptive's parameters mean nothing to DLS); null: the default
    dls = post(client, {"from_plan_id": paper["id"], "method": {"name": "dls"}, "feedback_gain": 1.5, "weights": None})
    assert dls["request"]["method"] == {"name": "dls", "params": {}} and dls["method"]["name"] == "dls"
    assert dls["request"]["feedback_gain"] == 1.5 and dls["request"]["weights"] == [0.5, 0.5]

    # another path type replaces the path whole; nulls remove the line's own fields
    waypoints = preset(client, "waypoint-inspection")["task"]
    patch = {"path": waypoints["path"], "target_position_m": None, "target_attitude_quaternion": None, "duration_s": None}
    moved = post(client, {"from_plan_id": paper["id"], "task": patch, "replay": False})
    assert moved["request"]["task"]["path"] == waypoints["path"]
    assert (
        moved["request"]["task"]["target_position_m"] is None and moved["request"]["task"]["q0_deg"] == EXAMPLE["task"]["q0_deg"]
    )
    assert moved["id"] in {
        p["id"] for p in client.get("/v1/plans", params={"path_type": "waypoints", "limit": 500}).json()["items"]
    }

    # robot_id and an inline robot: giving one drops the other
    table1 = client.get("/v1/robots/table1").json()["parameters"]
    inline = post(client, {"from_plan_id": paper["id"], "robot": table1, "replay": False})
    assert "robot_id" not in inline["request"] and inline["robot_id"] is None and "robot" in inline["request"]
    np.testing.assert_allclose(inline["metrics"]["position_error_max_m"], paper["metrics"]["position_error_max_m"], rtol=1e-12)
    back = post(client, {"from_plan_id": inline["id"], "robot_id": "table1"})
    assert back["robot_id"] == "table1" and "robot" not in back["request"]


def test_rerun_errors_name_the_merged_fields(client: httpx.Client, stored: dict[str, Any]) -> None:
    paper_id = stored["paper"]["id"]
    cases = [
        ({"task": {"dt_s": 0}}, "body.task.dt_s"),
        ({"method": {"params": {"gamma_max": 1.0}}}, "body.method.params"),
        ({"taks": {"dt_s": 0.5}}, "body.taks"),
        ({"feedback_gain": "fast"}, "body.feedback_gain"),
    ]
    for patch, field in cases:
        r = client.post("/v1/plans", json={"from_plan_id": paper_id, **patch})
        assert r.status_code == 422, (patch, r.text)
        assert r.json()["errors"][0]["field"].startswith(field), (patch, r.json())
    assert client.post("/v1/plans", json={"from_plan_id": "0" * 32}).status_code == 404
    assert client.post("/v1/plans", json={"from_plan_id": "nope"}).json()["errors"][0]["field"] == "body.from_plan_id"
    # a plain request's errors are as before
    r = client.post("/v1/plans", json={"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": "x"}})
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "body.task.dt_s"


def spacearm_plan(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "service", "plan", *args],
        cwd=ROOT,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_spacearm_plan_plans_a_file_without_a_server(client: httpx.Client, stored: dict[str, Any], tmp_path: Path) -> None:
    """The same body as POST /v1/plans, planned in a process of its own: the same verdict and
    metrics as the API's, the table of the plan page's rows, the trajectory in the format of its
    file name; exit 1 for a failed plan, 2 for an invalid request."""
    out = tmp_path / "paper.csv"
    done = spacearm_plan("examples/paper-plan.json", "--trajectory", str(out))
    print(f"\n{done.stdout}")
    assert done.returncode == 1, done.stderr  # the paper's own damping breaks 6 deg/s here
    api = client.post("/v1/plans", params={"fields": ""}, json=EXAMPLE).json()
    assert done.stdout.startswith(f"FAILED: {api['message']}")
    rows = {m[1]: m[2].split() for m in re.finditer(r"^  (\S.*?)\s{2,}(\S.*)$", done.stdout, re.M)}
    assert rows["max joint speed"] == [f"{api['metrics']['max_joint_speed_deg_s']:.4g}", "deg/s"]
    assert rows["max position error"] == [f"{api['metrics']['position_error_max_m'] * 1e3:.4g}", "mm"]
    assert rows["objective B"] == ["infeasible"] and rows["speed limit respected"] == ["no"]
    csv_api = client.get(f"/v1/plans/{api['id']}/trajectory", params={"format": "csv"}).content
    assert out.read_bytes() == csv_api

    body = json.dumps({**EXAMPLE, "method": {"name": "adaptive", "params": {"lambda_max": 0.04, "epsilon": 0.37}}})
    as_json = spacearm_plan("-", "--json", stdin=body)
    assert as_json.returncode == 0, as_json.stderr
    local = json.loads(as_json.stdout)
    assert local["metrics"] == stored["tuned"]["metrics"] and local["request"] == stored["tuned"]["request"]

    bad = spacearm_plan("-", stdin=json.dumps({"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 0}}))
    assert bad.returncode == 2 and "task.dt_s: Input should be greater than or equal to 0.0001" in bad.stderr
    unknown = spacearm_plan("-", stdin=json.dumps({"robot_id": "mine", "task": PAPER_TASK}))
    assert unknown.returncode == 2 and "'mine' is not a preset" in unknown.stderr
    rerun = spacearm_plan("-", stdin=json.dumps({"from_plan_id": "0" * 32}))
    assert rerun.returncode == 2 and "from_plan_id needs the server" in rerun.stderr


def test_a_line_without_a_duration_stores_the_15_s_it_used_and_a_raster_its_own_timing(
    client: httpx.Client, stored: dict[str, Any]
) -> None:
    """The default duration of a line (and an arc) is stored as used, 15 s; a raster's stays null,
    its own timing, so that a rerun with another scan speed retimes it."""
    task = {k: v for k, v in PAPER_TASK.items() if k != "duration_s"}
    line = post(client, {"robot_id": "table1", "task": task, "replay": False})
    assert line["request"]["task"]["duration_s"] == 15.0 and line["metrics"] == stored["paper"]["metrics"]
    assert stored["raster"]["request"]["task"]["duration_s"] is None
    faster = post(client, {"from_plan_id": stored["raster"]["id"], "task": {"path": {"scan_speed_m_s": 0.04}}, "replay": False})

    def duration(plan: dict[str, Any]) -> float:
        trajectory = client.get(f"/v1/plans/{plan['id']}", params={"fields": "trajectory"}).json()["trajectory"]
        return float(trajectory["t_s"][-1])

    assert duration(faster) < 0.7 * duration(stored["raster"])  # the passes twice as fast, not the turns


def test_metrics_in_degrees_come_back_as_given(stored: dict[str, Any]) -> None:
    """6 deg/s went to radians and back as 6.000000000000001: the degrees are given to 15 digits."""
    assert stored["paper"]["metrics"]["joint_speed_limit_deg_s"] == 6.0


def test_a_rerun_with_another_path_type_drops_the_old_paths_members(client: httpx.Client, stored: dict[str, Any]) -> None:
    """A line re-run as waypoints without nulls: the line's targets and its 15 s go (the targets
    were a 422, and the waypoints were rescaled to the line's duration); a duration given is kept."""
    waypoints = preset(client, "waypoint-inspection")["task"]
    moved = post(client, {"from_plan_id": stored["paper"]["id"], "task": {"path": waypoints["path"]}, "replay": False})
    task = moved["request"]["task"]
    assert task["path"] == waypoints["path"] and task["duration_s"] is None and task["target_position_m"] is None
    timed = post(client, {"from_plan_id": stored["paper"]["id"], "task": {"path": waypoints["path"], "duration_s": 90}})
    assert timed["request"]["task"]["duration_s"] == 90.0
