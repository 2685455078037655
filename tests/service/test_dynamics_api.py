"""Joint torques and torque limits over the API (issue 18): a plan's trajectory carries the
executed trajectory's accelerations, torques (forces) and mount wrench, as the engine computes
them, through storage and back; robots carry torque (force) limits, from parameters or URDF
``<limit effort>``, exported again; a plan over a limit is a 201 with ``success: false`` naming
the joint, the time and the value; bad limits are 422s naming the field; the figures render."""

from __future__ import annotations

import copy
import json
from typing import Any

import httpx
import numpy as np
import pytest

from engine import make_inverse, paper_task, plan, table1_robot
from engine.trajectory import PAPER_TASK_PARAMS
from tests.service.conftest import PAPER_TASK

PROBLEM = "application/problem+json"
TUNED = {"name": "adaptive", "params": PAPER_TASK_PARAMS["adaptive"]}


def _plan(client: httpx.Client, **body: Any) -> dict[str, Any]:
    r = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "method": TUNED, "replay": False, **body})
    assert r.status_code == 201, r.text
    out: dict[str, Any] = r.json()
    return out


def _array(rows: list[list[float | None]]) -> np.ndarray:
    return np.array([[np.nan if v is None else v for v in row] for row in rows], dtype=float)


def _fields(r: httpx.Response) -> list[str]:
    assert r.status_code == 422, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    return [e["field"] for e in r.json().get("errors") or []]


@pytest.fixture(scope="module")
def table1(stack: Any) -> dict[str, Any]:
    with stack.client() as c:
        params: dict[str, Any] = c.get("/v1/robots/table1").json()["parameters"]
    return params


def test_a_plan_returns_the_dynamics_of_its_executed_trajectory(client: httpx.Client) -> None:
    """The arrays as the engine computes them (the request's target quaternion is the paper's RPY
    to 1e-12, hence the tolerance), and as stored: the same numbers bit for bit."""
    created = _plan(client)
    stored = client.get(f"/v1/plans/{created['id']}").json()
    assert stored["trajectory"] == created["trajectory"] and stored["metrics"] == created["metrics"]
    expected = plan(table1_robot(), paper_task(), make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"]))
    traj = created["trajectory"]
    assert len(traj["joint_torques_n_m"]) == len(traj["t_s"]) == 61
    assert "joint_forces_n" not in traj and "joint_accelerations_m_s2" not in traj  # no prismatic joint
    for name, ours in (
        ("joint_torques_n_m", expected.joint_torques),
        ("joint_accelerations_deg_s2", np.degrees(expected.joint_accelerations)),
        ("mount_force_n", expected.mount_force),
        ("mount_torque_n_m", expected.mount_torque),
    ):
        np.testing.assert_allclose(_array(traj[name]), ours, rtol=0.0, atol=1e-9 * np.abs(ours).max(), err_msg=name)
    m = created["metrics"]
    assert m["max_joint_torque_n_m"] == np.abs(_array(traj["joint_torques_n_m"])).max()
    assert m["joint_torque_limit_respected"] is True and m["torque_limit_joint"] is None
    assert m["max_joint_force_n"] == 0.0 and created["success"] is True


def test_the_replay_says_how_executing_the_plan_changes_its_tracking(client: httpx.Client) -> None:
    """The executed trajectory replayed like the plan: the same numbers as the engine's
    replay_executed, a gap from the plan far below the tracking error but not zero (the base
    attitude depends on the joint path between the samples)."""
    from engine.executed import replay_executed

    replay = _plan(client, replay=True)["replay"]
    model = table1_robot()
    expected = replay_executed(model, plan(model, paper_task(), make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"])))
    assert replay["success"] is True and expected.success
    gap = replay["executed_plan_gap_position_max_m"]
    assert gap == pytest.approx(expected.plan_gap_position_max, rel=1e-6, abs=1e-12)
    assert replay["executed_path_position_error_max_m"] == pytest.approx(expected.path_position_error_max, rel=1e-6)
    assert 0.0 < gap < 0.05 * replay["path_position_error_max_m"], replay
    assert 0.0 < replay["executed_plan_gap_attitude_max_rad"] < 1e-3
    not_replayed = _plan(client)  # replay false: no replay section at all
    assert not_replayed.get("replay") is None


def test_prismatic_joints_get_forces_in_their_own_arrays(client: httpx.Client) -> None:
    preset = client.get("/v1/task-presets/arm3-position").json()
    r = client.post("/v1/plans", json={"robot_id": "arm3", "task": preset["task"], "method": {"name": "dls"}, "replay": False})
    assert r.status_code == 201, r.text
    body = r.json()
    traj, joints = body["trajectory"], client.get("/v1/robots/arm3").json()["joints"]
    slides = np.array([j["type"] == "prismatic" for j in joints])
    forces, torques = _array(traj["joint_forces_n"]), _array(traj["joint_torques_n_m"])
    assert np.all(np.isnan(forces[:, ~slides])) and np.all(np.isfinite(forces[:, slides]))
    assert np.all(np.isnan(torques[:, slides])) and np.all(np.isfinite(torques[:, ~slides]))
    assert np.all(np.isfinite(_array(traj["joint_accelerations_m_s2"])[:, slides]))
    # The URDF's <limit effort> values are the arm's limits, and the plan is checked against them.
    assert [j["torque_limit_n_m"] for j in joints] == [None, 40.0, None]  # the yaw joint is continuous, no <limit>
    assert [j["force_limit_n"] for j in joints] == [None, None, 100.0]
    assert body["metrics"]["max_joint_force_n"] == np.nanmax(np.abs(forces))


def test_torque_limits_round_trip_and_a_plan_over_one_fails_naming_it(client: httpx.Client, table1: dict[str, Any]) -> None:
    params = copy.deepcopy(table1)
    params["name"] = "weak shoulder"
    params["links"][1]["torque_limit_n_m"] = 1.0
    r = client.post("/v1/robots", json=params)
    assert r.status_code == 201, r.text
    robot = r.json()
    assert robot["parameters"]["links"][1]["torque_limit_n_m"] == 1.0
    assert [j["torque_limit_n_m"] for j in robot["joints"]] == [2.0, 1.0, 0.5, 0.5, 0.5, 0.5]
    urdf = client.get(f"/v1/robots/{robot['id']}/urdf").text
    assert 'effort="1.0"' in urdf and 'effort="5.0"' not in urdf
    again = client.post("/v1/robots", json={"urdf": urdf, "name": "from its URDF"})
    assert [j["torque_limit_n_m"] for j in again.json()["joints"]] == [2.0, 1.0, 0.5, 0.5, 0.5, 0.5]
    failed = _plan(client, robot_id=robot["id"])
    torques = _array(failed["trajectory"]["joint_torques_n_m"])
    first = failed["trajectory"]["t_s"][int(np.argmax(np.abs(torques[:, 1]) > 1.0))]
    assert failed["success"] is False
    assert (
        f"joint torque limit broken: joint 2 (joint2) needs up to {np.abs(torques[:, 1]).max():.4g} N m (limit 1 N m), "
        f"first over it at t = {first:g} s" in failed["message"]
    )
    m = failed["metrics"]
    assert m["joint_torque_limit_respected"] is False and m["objective_b"] is None
    assert m["torque_limit_joint"] == 2 and m["time_torque_limit_exceeded_s"] == first


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        ({"torque_limit_n_m": -1.0}, "body.links[1].torque_limit_n_m", "greater than 0"),
        ({"torque_limit_n_m": 0.0}, "body.links[1].torque_limit_n_m", "greater than 0"),
        ({"force_limit_n": 5.0}, "body.links[1].force_limit_n", "a revolute joint's effort limit is torque_limit_n_m"),
        (
            {"inertia": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]},
            "body.links[1].inertia",
            "has a torque_limit_n_m but no dynamics data",
        ),
    ],
)
def test_bad_limits_are_422s_naming_the_field(
    client: httpx.Client, table1: dict[str, Any], change: dict[str, Any], field: str, words: str
) -> None:
    params = copy.deepcopy(table1)
    params["links"][1].update(change)
    r = client.post("/v1/robots", json=params)
    assert _fields(r) == [field]
    assert words in json.dumps(r.json())
    inline = client.post("/v1/plans", json={"robot": params, "task": PAPER_TASK, "replay": False})
    assert _fields(inline) == [field.replace("body.", "body.robot.")]


def test_a_non_finite_limit_is_a_422_naming_the_field(client: httpx.Client, table1: dict[str, Any]) -> None:
    text = json.dumps(table1).replace('"torque_limit_n_m": 5.0', '"torque_limit_n_m": NaN')
    assert "NaN" in text
    r = client.post("/v1/robots", content=text.encode(), headers={"content-type": "application/json"})
    assert _fields(r) == ["body.links[1].torque_limit_n_m"]


def test_torque_and_wrench_figures(client: httpx.Client) -> None:
    tuned = _plan(client)
    bounded = _plan(client, method={"name": "bounded", "params": {"lambda": 0.02}})  # over joint 4's limit at 7.5 s
    assert bounded["success"] is False and "joint 4 (joint4) needs up to" in bounded["message"]
    for name in ("joint-torques", "carrier-wrench"):
        r = client.get(f"/v1/plans/{bounded['id']}/figures/{name}")
        assert r.status_code == 200 and r.headers["content-type"].startswith("image/svg+xml"), r.text
        assert b"joint" in r.content or b"carrier" in r.content
    r = client.get("/v1/plans/compare/figures/joint-torques", params={"ids": f"{tuned['id']},{bounded['id']}"})
    assert r.status_code == 200 and b"Joint torques compared" in r.content
    png = client.get(f"/v1/plans/{tuned['id']}/figures/joint-torques", params={"format": "png"})
    assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
