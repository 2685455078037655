"""One test per input rule of the hardening issue: every bad input is a 422 problem+json that
names the field path; a target the arm cannot reach or a diverging plan is a 201 with
``success: false``, a message and the metrics."""

from __future__ import annotations

import copy
import json
import time
from typing import Any

import httpx
import pytest

from tests.service.conftest import PAPER_TASK, job_body

PROBLEM = "application/problem+json"


def _fields(r: httpx.Response, status: int = 422) -> list[str]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM)
    body = r.json()
    assert body["status"] == status and body["detail"]
    return [e["field"] for e in body.get("errors") or []]


def _plan(client: httpx.Client, task: dict[str, Any] | None = None, **extra: Any) -> httpx.Response:
    return client.post("/v1/plans", json={"robot_id": "table1", "task": {**PAPER_TASK, **(task or {})}, "replay": False, **extra})


def _raw(client: httpx.Client, path: str, text: str) -> httpx.Response:
    return client.post(path, content=text.encode(), headers={"content-type": "application/json"})


@pytest.fixture(scope="module")
def robot(stack: Any) -> dict[str, Any]:
    with stack.client() as c:
        params: dict[str, Any] = c.get("/v1/robots/table1").json()["parameters"]
    return params


# --- every number finite: JSON NaN / Infinity literals (Python's json accepts them) and overflow


@pytest.mark.parametrize(
    ("literal", "where", "field"),
    [
        ("NaN", '"dt_s": 0.25', "body.task.dt_s"),
        ("Infinity", '"duration_s": 15.0', "body.task.duration_s"),
        ("-Infinity", '"ramp_time_s": 1.5', "body.task.ramp_time_s"),
        ("1e400", '"joint_speed_limit_deg_s": 6.0', "body.task.joint_speed_limit_deg_s"),
    ],
)
def test_non_finite_task_numbers_rejected(client: httpx.Client, literal: str, where: str, field: str) -> None:
    text = json.dumps({"robot_id": "table1", "task": PAPER_TASK, "replay": False})
    assert where in text
    key = where.split(":")[0]
    assert _fields(_raw(client, "/v1/plans", text.replace(where, f"{key}: {literal}"))) == [field]


def test_non_finite_vector_elements_rejected(client: httpx.Client) -> None:
    text = json.dumps({"robot_id": "table1", "task": PAPER_TASK, "replay": False})
    assert _fields(_raw(client, "/v1/plans", text.replace('"q0_deg": [175.0', '"q0_deg": [NaN'))) == ["body.task.q0_deg[0]"]
    bad = text.replace('"target_position_m": [1.5, 0.0', '"target_position_m": [1.5, Infinity')
    assert _fields(_raw(client, "/v1/plans", bad)) == ["body.task.target_position_m[1]"]
    bad = text[:-1] + ', "method": {"name": "dls", "params": {"lambda": NaN}}}'
    assert _fields(_raw(client, "/v1/plans", bad)) == ["body.method.params.lambda"]
    bad = text[:-1] + ', "weights": [0.5, Infinity]}'
    assert _fields(_raw(client, "/v1/plans", bad)) == ["body.weights[1]"]
    bad = text[:-1] + ', "feedback_gain": NaN}'
    assert _fields(_raw(client, "/v1/plans", bad)) == ["body.feedback_gain"]
    jac = '{"joint_angles_deg": [0, 0, NaN, 0, 0, 0]}'
    assert _fields(_raw(client, "/v1/robots/table1/jacobian", jac)) == ["body.joint_angles_deg[2]"]


def test_non_finite_robot_and_job_numbers_rejected(client: httpx.Client, robot: dict[str, Any]) -> None:
    text = json.dumps(robot)
    bad = text.replace('"mass": ', '"mass": NaN, "ignored": ', 1)  # the first mass is the base's
    assert "body.base.mass" in _fields(_raw(client, "/v1/robots", bad))
    job = json.dumps({**job_body(), "bounds": {"lambda_max": [0.0777, 0.2]}}).replace("0.0777", "-Infinity")
    assert _fields(_raw(client, "/v1/tuning-jobs", job)) == ["body.bounds.lambda_max[0]"]


# --- robots


@pytest.mark.parametrize("where", ["base", "links"])
@pytest.mark.parametrize("mass", [0.0, -3.0])
def test_masses_positive(client: httpx.Client, robot: dict[str, Any], where: str, mass: float) -> None:
    params = copy.deepcopy(robot)
    if where == "base":
        params["base"]["mass"] = mass
        field = "body.base.mass"
    else:
        params["links"][3]["mass"] = mass
        field = "body.links[3].mass"
    assert _fields(client.post("/v1/robots", json=params)) == [field]


@pytest.mark.parametrize(
    ("inertia", "why"),
    [
        ([[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "symmetric"),
        ([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]], "a principal moment is negative, -1 kg m^2"),
        ([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "not zero or singular"),
        ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 5.0]], "triangle inequality"),
    ],
)
def test_inertia_tensor_rules(client: httpx.Client, robot: dict[str, Any], inertia: list[list[float]], why: str) -> None:
    params = copy.deepcopy(robot)
    params["links"][1]["inertia"] = inertia
    r = client.post("/v1/robots", json=params)
    assert _fields(r) == ["body.links[1].inertia"]
    assert why in r.json()["detail"]
    assert ("no dynamics data" in r.json()["detail"]) == ("singular" in why)  # Table 1's links have torque limits
    params = copy.deepcopy(robot)
    params["base"]["inertia"] = inertia
    assert _fields(client.post("/v1/robots", json=params)) == ["body.base.inertia"]


def test_joint_axis_non_zero(client: httpx.Client, robot: dict[str, Any]) -> None:
    params = copy.deepcopy(robot)
    params["links"][4]["joint_axis"] = [0.0, 0.0, 0.0]
    assert _fields(client.post("/v1/robots", json=params)) == ["body.links[4].joint_axis"]


@pytest.mark.parametrize("n", [0, 13])
def test_one_to_twelve_joints(client: httpx.Client, robot: dict[str, Any], n: int) -> None:
    params = copy.deepcopy(robot)
    params["links"] = (robot["links"] * 3)[:n]
    assert _fields(client.post("/v1/robots", json=params)) == ["body.links"]
    inline = client.post("/v1/plans", json={"robot": params, "task": PAPER_TASK, "replay": False})
    assert _fields(inline) == ["body.robot.links"]


# --- tasks


def test_quaternion_non_zero_norm_and_normalised(client: httpx.Client) -> None:
    assert _fields(_plan(client, {"target_attitude_quaternion": [0.0, 0.0, 0.0, 0.0]})) == [
        "body.task.target_attitude_quaternion"
    ]
    r = client.post(
        "/v1/robots/table1/jacobian", json={"joint_angles_deg": PAPER_TASK["q0_deg"], "base_attitude_quaternion": [0, 0, 0, 0]}
    )
    assert _fields(r) == ["body.base_attitude_quaternion"]
    # a non-unit quaternion is normalised: twice the paper's target is the same attitude
    doubled = [2 * x for x in PAPER_TASK["target_attitude_quaternion"]]
    a, b = _plan(client, {"target_attitude_quaternion": doubled}), _plan(client)
    assert a.status_code == b.status_code == 201, a.text
    assert a.json()["metrics"]["position_error_max_m"] == pytest.approx(b.json()["metrics"]["position_error_max_m"], rel=1e-9)
    assert a.json()["metrics"]["attitude_error_max_rad"] == pytest.approx(b.json()["metrics"]["attitude_error_max_rad"], rel=1e-9)


def test_q0_length_equals_joints(client: httpx.Client) -> None:
    assert _fields(_plan(client, {"q0_deg": [0.0] * 5})) == ["body.task.q0_deg"]
    assert _fields(client.post("/v1/robots/table1/jacobian", json={"joint_angles_deg": [0.0] * 7})) == ["body.joint_angles_deg"]
    job = {**job_body(), "tasks": [PAPER_TASK, {**PAPER_TASK, "q0_deg": [1.0, 2.0]}]}
    assert _fields(client.post("/v1/tuning-jobs", json=job)) == ["body.tasks[1].q0_deg"]


@pytest.mark.parametrize("dt", [0.0, -0.1, 1.0001, 5.0])
def test_dt_in_zero_one(client: httpx.Client, dt: float) -> None:
    assert _fields(_plan(client, {"dt_s": dt})) == ["body.task.dt_s"]


def test_dt_of_one_is_accepted(client: httpx.Client) -> None:
    assert _plan(client, {"dt_s": 1.0, "ramp_time_s": 1.0}).status_code == 201


def test_dt_longer_than_the_path_is_refused(client: httpx.Client) -> None:
    """One step longer than the whole path planned the motion over dt, not the duration asked for:
    a 10 ms move planned as a 1 s one passed the speed limit it breaks by far."""
    r = _plan(client, {"dt_s": 1.0, "duration_s": 0.01, "ramp_time_s": 0.0})
    assert _fields(r) == ["body.task.dt_s"] and "must not exceed the path's duration, 0.01 s" in r.json()["detail"]
    assert _plan(client, {"dt_s": 0.5, "duration_s": 0.5, "ramp_time_s": 0.0}).status_code == 201  # one step: allowed


@pytest.mark.parametrize("ramp", [-0.5, 7.51])
def test_ramp_between_zero_and_half_duration(client: httpx.Client, ramp: float) -> None:
    assert _fields(_plan(client, {"ramp_time_s": ramp})) == ["body.task.ramp_time_s"]
    assert _plan(client, {"ramp_time_s": 7.5}).status_code == 201  # exactly duration / 2


def test_duration_at_most_600(client: httpx.Client) -> None:
    assert _fields(_plan(client, {"duration_s": 600.5})) == ["body.task.duration_s"]
    assert _fields(_plan(client, {"duration_s": 0.0})) == ["body.task.duration_s"]


def test_at_most_20000_steps(client: httpx.Client) -> None:
    r = _plan(client, {"duration_s": 500.0, "dt_s": 0.02})  # 25,000 steps
    assert _fields(r) == ["body.task.dt_s"]
    assert "20000" in r.json()["detail"]


# --- GA jobs


@pytest.mark.parametrize("population", [1, 1001])
def test_ga_population_2_to_1000(client: httpx.Client, population: int) -> None:
    r = client.post("/v1/tuning-jobs", json={**job_body(), "ga": {"population": population, "generations": 1}})
    assert _fields(r) == ["body.ga.population"]


@pytest.mark.parametrize("generations", [0, 1001])
def test_ga_generations_1_to_1000(client: httpx.Client, generations: int) -> None:
    r = client.post("/v1/tuning-jobs", json={**job_body(), "ga": {"population": 4, "generations": generations}})
    assert _fields(r) == ["body.ga.generations"]


def test_at_most_200000_plan_evaluations(client: httpx.Client) -> None:
    # 400 * (249 + 1) * 1 * 2 = 200,000 is the limit; one generation more is over it
    over = client.post("/v1/tuning-jobs", json={**job_body(), "ga": {"population": 400, "generations": 250}})
    assert _fields(over) == ["body.ga"]
    assert "200000" in over.json()["detail"]
    tasks = client.post(
        "/v1/tuning-jobs", json={**job_body(), "tasks": [PAPER_TASK] * 3, "ga": {"population": 500, "generations": 100}}
    )
    assert _fields(tasks) == ["body.ga"]  # 500 * 101 * 3 * 2


def test_bounds_lo_below_hi_within_range(client: httpx.Client) -> None:
    r = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"lambda_max": [0.2, 0.1]}})
    assert _fields(r) == ["body.bounds.lambda_max"]
    r = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"epsilon": [0.1, 0.1]}})
    assert _fields(r) == ["body.bounds.epsilon"]
    r = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"lambda_max": [-1.0, 0.1]}})
    assert _fields(r) == ["body.bounds.lambda_max"]
    r = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"lambda_max": [0.1, 0.2, 0.3]}})
    assert _fields(r) == ["body.bounds.lambda_max"]
    r = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"gamma": [0.1, 0.2]}})
    assert _fields(r) == ["body.bounds.gamma"]
    assert "valid: lambda_max, epsilon" in r.json()["detail"]


def test_unknown_method_lists_valid_ones(client: httpx.Client) -> None:
    r = _plan(client, method={"name": "magic"})
    assert _fields(r) == ["body.method.name"]
    for name in ("inverse", "dls", "adaptive", "wdls", "sdls", "svf"):
        assert name in r.json()["detail"]
    r = client.post("/v1/tuning-jobs", json={**job_body(), "method": "magic"})
    assert _fields(r) == ["body.method"]
    assert "adaptive" in r.json()["detail"] and "dls" in r.json()["detail"]
    r = _plan(client, method={"name": "dls", "params": {"lambda": 0.01, "mu": 1.0}})
    assert _fields(r) == ["body.method.params.mu"]
    assert "valid: lambda" in r.json()["detail"]


def test_method_parameter_range(client: httpx.Client) -> None:
    assert _fields(_plan(client, method={"name": "dls", "params": {"lambda": -1.0}})) == ["body.method.params.lambda"]


# --- results that are not errors


def test_unreachable_target_is_a_result_not_an_error(client: httpx.Client) -> None:
    r = _plan(client, {"target_position_m": [50.0, 0.0, 0.0]})
    assert r.status_code == 201, r.text
    plan = r.json()
    assert plan["success"] is False and plan["message"]
    assert "metrics" in plan and plan["metrics"]["joint_speed_limit_respected"] is False


def test_diverging_plan_is_a_result_not_an_error(client: httpx.Client) -> None:
    # a plain inverse through the singularity with a huge feedback gain: absurd joint rates
    start = time.monotonic()
    body = {"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "svf"}, "feedback_gain": 5e5, "replay": True}
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 201, r.text
    assert time.monotonic() - start < 20  # the replay of such a plan used to run for minutes
    plan = r.json()
    assert plan["success"] is False and plan["message"]
    assert plan["metrics"]["objective_b"] is None and plan["metrics"]["joint_speed_limit_respected"] is False
    assert plan["replay"]["success"] is False and plan["replay"]["message"].startswith("not replayed")


# --- 4xx details


def test_malformed_bodies_are_problems_naming_the_body(client: httpx.Client) -> None:
    """JSON that does not parse is an error of the body with the parser's reason and where it
    stopped (it was ``body[22]: JSON decode error``, which reads as an array index); JSON nested
    deeper than the parser goes says so (it said "not valid JSON (UTF-8)")."""
    r = _raw(client, "/v1/plans", '{"robot_id": "table1",')
    assert _fields(r) == ["body"]
    expected = "body: not valid JSON: Expecting property name enclosed in double quotes at char 22 (counted from 0)"
    assert r.json()["detail"] == expected
    r = _raw(client, "/v1/plans", "[" * 100_000 + "]" * 100_000)
    assert _fields(r) == ["body"] and "nested too deeply" in r.json()["detail"], r.text
    r = client.post("/v1/plans", content=b"\x80\x81garbage", headers={"content-type": "application/json"})
    assert _fields(r)[0].startswith("body")
    assert _fields(client.get("/v1/plans", params={"offset": 10**20})) == ["query.offset"]


@pytest.mark.parametrize(
    "path",
    ["/v1/plans", "/v1/robots", "/v1/robots/table1/jacobian", "/v1/tuning-jobs", "/v1/landscapes", "/v1/plans/shortest-duration"],
)
def test_a_json_body_sent_as_another_media_type_is_a_415_that_says_so(client: httpx.Client, path: str) -> None:
    """Valid JSON as ``text/plain``, or form-encoded (``curl -d`` without ``-H``), is a 415 whose
    detail names the type and JSON (it was a 422 "body: Input should be a valid dictionary")."""
    text = json.dumps({"robot_id": "table1", "task": PAPER_TASK, "replay": False}).encode()
    for content_type in ("text/plain", "application/x-www-form-urlencoded", "application/xml"):
        r = client.post(path, content=text, headers={"content-type": content_type})
        assert r.status_code == 415, (path, content_type, r.text)
        assert r.headers["content-type"].startswith(PROBLEM)
        assert f"Content-Type {content_type!r} is not JSON" in r.json()["detail"] and "application/json" in r.json()["detail"]


def test_json_media_types_are_read_and_a_body_without_a_content_type_is_a_415(client: httpx.Client) -> None:
    body = json.dumps({"robot_id": "table1", "task": PAPER_TASK, "replay": False}).encode()
    for content_type in ("application/json; charset=utf-8", "application/merge-patch+json"):
        r = client.post("/v1/plans", params={"fields": ""}, content=body, headers={"content-type": content_type})
        assert r.status_code == 201, (content_type, r.text)
    r = client.post("/v1/plans", content=body)
    assert r.status_code == 415 and "a body without Content-Type" in r.json()["detail"]
    assert _fields(client.post("/v1/plans")) == ["body"]  # no body at all: the 422 names it


def test_a_number_of_5000_digits_is_named_as_such(client: httpx.Client) -> None:
    """Python refuses integer text longer than 4,300 digits (quadratic parsing); the body is JSON
    all the same, so the message says which rule it broke (it said "not valid JSON")."""
    r = _raw(client, "/v1/plans", '{"robot_id": "table1", "task": {"duration_s": ' + "1" * 5000 + "}}")
    assert _fields(r) == ["body"] and "has more than 4300 digits" in r.json()["detail"]


@pytest.mark.parametrize("path", ["/v1/plans", "/v1/plans/shortest-duration", "/v1/tuning-jobs", "/v1/landscapes"])
def test_posts_that_answer_json_refuse_an_accept_without_it_and_vary_on_it(client: httpx.Client, path: str) -> None:
    """``Accept: text/csv`` on a resource that answers JSON only is a 406 before any work (the
    shortest-duration, tuning-job and landscape POSTs ignored it and answered JSON), and a 406
    says ``Vary: Accept``."""
    r = client.post(path, json={"robot_id": "table1", "task": PAPER_TASK}, headers={"accept": "text/csv"})
    assert r.status_code == 406, r.text
    assert r.headers["vary"] == "Accept" and r.json()["available"] == ["application/json"]


def test_revolute_limits_that_look_like_degrees_are_noted(client: httpx.Client, robot: dict[str, Any]) -> None:
    """A parameter set's limits are radians; ``{"lower": -170, "upper": 170}`` is 54 turns, kept
    as given (multi-turn joints exist) but said in the robot's notes."""
    params = copy.deepcopy(robot)
    params["name"] = "degrees-as-radians"
    params["links"][1]["limits"] = {"lower": -170.0, "upper": 170.0}
    r = client.post("/v1/robots", json=params)
    assert r.status_code == 201, r.text
    (note,) = [n for n in r.json()["notes"] if "radians" in n]
    assert "joint2 (-170 to 170 rad)" in note
    params["links"][1]["limits"] = {"lower": -3.0, "upper": 3.0}
    assert not [n for n in client.post("/v1/robots", json=params).json()["notes"] if "radians" in n]


def test_a_robust_statistic_without_uncertainty_is_refused(client: httpx.Client) -> None:
    """``p95`` or ``max`` over samples the job does not draw was accepted and meant nothing; ``mean``,
    the default that every stored request carries, stays valid."""
    for statistic in ("p95", "max"):
        r = client.post("/v1/tuning-jobs", json={**job_body(), "robust_statistic": statistic})
        assert _fields(r) == ["body.robust_statistic"] and "needs `uncertainty`" in r.json()["detail"]


def test_prismatic_positions_are_lengths_within_a_kilometre(client: httpx.Client) -> None:
    """``joint_displacements_m`` and ``q0_m`` had the angles' bound (36,000, in metres)."""
    state: dict[str, Any] = {"joint_angles_deg": [0, 20, None], "joint_displacements_m": [None, None, 3e4]}
    r = client.post("/v1/robots/arm3/jacobian", json=state)
    assert r.status_code == 422 and _fields(r) == ["body.joint_displacements_m[2]"], r.text
    r = client.post("/v1/robots/arm3/jacobian", json={**state, "joint_displacements_m": [None, None, 30]})
    assert r.status_code == 200, r.text  # outside the boom's limits (0 to 0.5 m), and documented as allowed
