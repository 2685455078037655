"""Robots from URDF over HTTP: creation (the URDF as text in the JSON field ``urdf``), the derived
parameter set, joints and units, the export at ``/urdf``, every refusal as a 422 naming the URDF
element, and the example robots planned, tuned, replayed and drawn end to end."""

from __future__ import annotations

import math
from typing import Any

import httpx
import numpy as np
import pinocchio as pin
import pytest

from engine import RobotModel, table1_robot
from engine.model import urdf_preset_text
from tests.service.conftest import PAPER_TASK, wait_status

PROBLEM = "application/problem+json"


def _problem(r: httpx.Response, status: int = 422) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body: dict[str, Any] = r.json()
    return body


def _preset_task(client: httpx.Client, name: str) -> tuple[str, dict[str, Any]]:
    preset = client.get(f"/v1/task-presets/{name}").json()
    return preset["robot_id"], preset["task"]


def test_create_a_robot_from_urdf(client: httpx.Client) -> None:
    r = client.post("/v1/robots", json={"urdf": urdf_preset_text("arm7"), "end_effector_link": "tool0", "name": "my-arm7"})
    assert r.status_code == 201, r.text
    robot = r.json()
    assert robot["name"] == "my-arm7" and robot["n_joints"] == 7 and not robot["preset"]
    assert [j["name"] for j in robot["joints"]][:2] == ["shoulder_yaw", "shoulder_pitch"]
    assert all(j["type"] == "revolute" and j["unit"] == "deg" for j in robot["joints"])
    assert robot["joints"][3]["lower_deg"] == pytest.approx(-150.0) and robot["notes"] == []
    params = robot["parameters"]
    assert params["base"]["mass"] == 483.0 and params["base"]["name"] == "spacecraft"  # mounting plate merged
    assert RobotModel.from_dict(params).n_joints == 7
    # The stored robot exports a URDF that the importer and Pinocchio read back to the same model.
    exported = client.get(f"/v1/robots/{robot['id']}/urdf")
    assert exported.status_code == 200 and exported.headers["content-type"].startswith("application/xml")
    again = RobotModel.from_urdf(exported.text)
    np.testing.assert_allclose(again.inertias, RobotModel.from_dict(params).inertias, atol=1e-12)
    pm = pin.buildModelFromXML(exported.text, pin.JointModelFreeFlyer())
    assert pm.nv == 6 + 7
    # A tool offset moves the end-effector frame: 0.1 m along the tool frame's z.
    tool = client.post(
        "/v1/robots",
        json={"urdf": urdf_preset_text("arm7"), "tool_position_m": [0.0, 0.0, 0.1], "tool_attitude_quaternion": [1, 0, 0, 0]},
    ).json()
    C_e = np.array(params["end_effector"]["C_e"])
    shift = np.array(tool["parameters"]["links"][-1]["b"]) - np.array(params["links"][-1]["b"])
    np.testing.assert_allclose(shift, C_e @ [0.0, 0.0, 0.1], atol=1e-12)


def test_presets_and_their_urdf(client: httpx.Client) -> None:
    arm3 = client.get("/v1/robots/arm3").json()
    assert arm3["preset"] and arm3["n_joints"] == 3
    assert [(j["type"], j["unit"]) for j in arm3["joints"]] == [("revolute", "deg"), ("revolute", "deg"), ("prismatic", "m")]
    assert arm3["joints"][2]["lower_m"] == 0.0 and arm3["joints"][2]["upper_m"] == 0.5
    assert arm3["joints"][0]["lower_deg"] is None and "yaw" in arm3["notes"][0]  # continuous: unlimited, and said so
    assert client.get("/v1/robots/arm7").json()["n_joints"] == 7
    table1 = client.get("/v1/robots/table1/urdf").text
    np.testing.assert_allclose(RobotModel.from_urdf(table1).b_vectors, table1_robot().b_vectors, atol=1e-15)
    _problem(client.get("/v1/robots/nope/urdf"), 404)


def test_table1_urdf_posted_back_gives_the_same_paper_plan(client: httpx.Client) -> None:
    urdf = client.get("/v1/robots/table1/urdf").text
    robot = client.post("/v1/robots", json={"urdf": urdf}).json()
    body = {"task": PAPER_TASK, "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}}, "replay": False}
    ours = client.post("/v1/plans", params={"fields": ""}, json={**body, "robot_id": "table1"}).json()["metrics"]
    theirs = client.post("/v1/plans", params={"fields": ""}, json={**body, "robot_id": robot["id"]}).json()["metrics"]
    for key in ("objective_b", "position_error_max_m", "attitude_error_max_rad", "max_joint_speed_deg_s", "min_abs_det_gjm"):
        assert theirs[key] == pytest.approx(ours[key], rel=1e-9), key


def _arm(extra: str = "") -> str:
    inertia = '<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial>'
    joint = '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><limit lower="-1" upper="1"/></joint>'
    return f"""<robot name="r"><link name="base">{inertia}</link><link name="l1">{inertia}</link>{joint}{extra}</robot>"""


@pytest.mark.parametrize(
    ("body", "element", "words"),
    [
        ({"urdf": "<robot name='r'><link name='a'>"}, "<robot>", "not well-formed"),
        ({"urdf": _arm(), "end_effector_link": "flange"}, '<link name="flange">', "no such link"),
        (
            {"urdf": _arm('<joint name="j2" type="fixed"><parent link="l1"/><child link="gone"/></joint>')},
            '<joint name="j2">',
            "gone",
        ),
        (
            {"urdf": _arm('<link name="l2"/><joint name="free" type="floating"><parent link="l1"/><child link="l2"/></joint>')},
            '<joint name="free">',
            "floating",
        ),
        (
            {
                "urdf": _arm(
                    '<link name="l2"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>'
                    '</inertial></link><joint name="j2" type="revolute"><parent link="base"/><child link="l2"/></joint>'
                )
            },
            '<joint name="j2">',
            "second moving branch",
        ),
        (
            {"urdf": _arm('<link name="l2"/><joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/></joint>')},
            '<link name="l2">',
            "zero mass",
        ),
        (
            {
                "urdf": _arm(
                    '<link name="l2"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="9"/>'
                    '</inertial></link><joint name="j2" type="fixed"><parent link="l1"/><child link="l2"/></joint>'
                )
            },
            '<link name="l2">',
            "non-physical inertia",
        ),
    ],
)
def test_urdf_refusals_are_422_naming_the_element(client: httpx.Client, body: dict[str, Any], element: str, words: str) -> None:
    problem = _problem(client.post("/v1/robots", json=body))
    assert problem["element"] == element
    assert element in problem["detail"] and words in problem["detail"]
    field = "body.end_effector_link" if "end_effector_link" in body else "body.urdf"
    assert [e["field"] for e in problem["errors"]] == [field]


def test_urdf_body_validation(client: httpx.Client) -> None:
    fields = [e["field"] for e in _problem(client.post("/v1/robots", json={"urdf": 3}))["errors"]]
    assert fields == ["body.urdf"]
    bad_tool = {"urdf": urdf_preset_text("arm3"), "tool_attitude_quaternion": [0, 0, 0, 0]}
    assert [e["field"] for e in _problem(client.post("/v1/robots", json=bad_tool))["errors"]] == ["body.tool_attitude_quaternion"]
    # A parameter set is still validated as before.
    assert "body.base" in [e["field"] for e in _problem(client.post("/v1/robots", json={"name": "x", "links": []}))["errors"]]


def test_three_joint_arm_position_plan_with_units_per_joint(client: httpx.Client) -> None:
    robot_id, task = _preset_task(client, "arm3-position")
    r = client.post("/v1/plans", json={"robot_id": robot_id, "task": task, "method": {"name": "dls"}, "feedback_gain": 0.5})
    assert r.status_code == 201, r.text
    plan = r.json()
    assert plan["success"], plan["message"]
    m = plan["metrics"]
    assert m["tracks"] == "position" and m["min_abs_det_gjm"] > 0  # the 3x3 position Jacobian is square
    assert 0 < m["max_linear_joint_speed_m_s"] <= 0.05 and m["position_limits_respected"]
    traj = plan["trajectory"]
    assert traj["joint_angles_deg"][0] == [0.0, pytest.approx(20.0), None]
    assert traj["joint_displacements_m"][0] == [None, None, pytest.approx(0.2)]
    assert plan["replay"]["success"] and plan["replay"]["plan_gap_position_max_m"] < 1e-9
    # Figures draw it like any plan.
    assert client.get(f"/v1/plans/{plan['id']}/figures/joint-angles").status_code == 200
    # A pose task on three joints is a 422 that says so.
    pose = {**task, "tracks": "pose", "target_attitude_quaternion": [1, 0, 0, 0]}
    problem = _problem(client.post("/v1/plans", json={"robot_id": robot_id, "task": pose}))
    assert [e["field"] for e in problem["errors"]] == ["body.task.tracks"]
    assert "pose task needs at least 6 joints; this robot has 3" in problem["detail"]
    # Each joint's position in the list of its unit.
    wrong = {**task, "q0_deg": [0.0, 20.0, 0.2], "q0_m": None}
    fields = [e["field"] for e in _problem(client.post("/v1/plans", json={"robot_id": robot_id, "task": wrong}))["errors"]]
    assert fields == ["body.task.q0_m[2]"]
    outside = {**task, "q0_m": [None, None, 0.7]}
    problem = _problem(client.post("/v1/plans", json={"robot_id": robot_id, "task": outside}))
    assert [e["field"] for e in problem["errors"]] == ["body.task.q0_m[2]"] and "outside the limits" in problem["detail"]
    jac = client.post(
        f"/v1/robots/{robot_id}/jacobian", json={"joint_angles_deg": [0, 20, None], "joint_displacements_m": [None, None, 0.2]}
    )
    assert jac.status_code == 200 and jac.json()["determinant"] is None and len(jac.json()["gjm"][0]) == 3


def test_seven_joint_arm_keeps_its_carrier_stiller(client: httpx.Client) -> None:
    robot_id, task = _preset_task(client, "arm7-line")
    body = {"robot_id": robot_id, "task": task, "method": {"name": "adaptive", "params": {"lambda_max": 0.05, "epsilon": 0.05}}}
    body["feedback_gain"] = 1.0
    plain = client.post("/v1/plans", json=body).json()
    still = client.post("/v1/plans", json={**body, "secondary": {"objective": "min_base_rotation", "gain": 0.5}}).json()
    assert plain["success"] and still["success"], still["message"]
    assert still["metrics"]["base_attitude_change_max_rad"] < 0.8 * plain["metrics"]["base_attitude_change_max_rad"]
    assert still["metrics"]["min_abs_det_gjm"] is None and len(still["trajectory"]["singular_values"][0]) == 6
    assert still["method"]["secondary"] == {"objective": "min_base_rotation", "gain": 0.5}
    assert still["replay"]["success"]
    for gain in (1.5, -1.0):
        problem = _problem(client.post("/v1/plans", json={**body, "secondary": {"objective": "min_base_rotation", "gain": gain}}))
        assert problem["errors"][0]["field"].startswith("body.secondary")
    six = {"robot_id": "table1", "task": PAPER_TASK, "secondary": {"objective": "joint_centering"}}
    problem = _problem(client.post("/v1/plans", json=six))
    assert [e["field"] for e in problem["errors"]] == ["body.secondary"] and "redundant" in problem["detail"]


def test_tuning_a_three_joint_arm(client: httpx.Client) -> None:
    robot_id, task = _preset_task(client, "arm3-position")
    job = {"robot_id": robot_id, "tasks": [task], "method": "adaptive", "ga": {"population": 4, "generations": 2, "seed": 1}}
    r = client.post("/v1/tuning-jobs", json=job)
    assert r.status_code == 202, r.text
    done = wait_status(client, r.json()["id"], ("succeeded", "failed"))
    assert done["status"] == "succeeded", done
    result = client.get(f"/v1/tuning-jobs/{done['id']}/result").json()
    metrics = result["best_metrics"][0]
    assert metrics["tracks"] == "position"
    assert result["best_objective_b"] == pytest.approx(0.5 * metrics["position_error_max_m"])
    assert math.isfinite(result["dls_baseline"]["objective_b"])
