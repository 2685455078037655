"""Objective landscapes over real HTTP: the grid, its heatmap with a tuning job's marks, the
work bound and the 422s naming the field, deletion."""

from __future__ import annotations

import re
from typing import Any

import httpx

from tests.service.conftest import PAPER_TASK, job_body, wait_status


def landscape_body(**overrides: Any) -> dict[str, Any]:
    return {
        "robot_id": "table1",
        "tasks": [PAPER_TASK],
        "method": "adaptive",
        "x": {"name": "lambda_max", "min": 0.001, "max": 0.2, "steps": 24},
        "y": {"name": "epsilon", "min": 0.001, "max": 1.0, "steps": 20, "scale": "log"},
        **overrides,
    }


def test_landscape_grid_heatmap_and_marks(client: httpx.Client) -> None:
    job = client.post("/v1/tuning-jobs", json=job_body(population=10, generations=4)).json()
    wait_status(client, job["id"], ("succeeded",))
    tuned = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
    r = client.post("/v1/landscapes", json=landscape_body(tuning_job_id=job["id"]))
    assert r.status_code == 201, r.text
    land = r.json()
    assert r.headers["location"] == land["links"]["self"] == f"/v1/landscapes/{land['id']}"
    assert (land["x"]["name"], len(land["x"]["values"]), land["x"]["scale"]) == ("lambda_max", 24, "linear")
    assert (land["y"]["name"], len(land["y"]["values"]), land["y"]["scale"]) == ("epsilon", 20, "log")
    assert land["y"]["values"][0] == 0.001 and abs(land["y"]["values"][-1] - 1.0) < 1e-12
    b, feasible, speed = land["objective_b"], land["feasible"], land["max_joint_speed_deg_s"]
    assert len(b) == len(feasible) == len(speed) == 24 and all(len(row) == 20 for row in b)
    cells = [(i, j) for i in range(24) for j in range(20)]
    assert all((b[i][j] is None) == (not feasible[i][j]) for i, j in cells)
    assert all(speed[i][j] <= 6.0 + 1e-9 for i, j in cells if feasible[i][j])  # the paper task's limit
    assert any(speed[i][j] is not None and speed[i][j] > 6.0 for i, j in cells if not feasible[i][j])
    best = min((b[i][j], i, j) for i, j in cells if feasible[i][j])
    assert land["best_objective_b"] == best[0]
    assert land["best_params"] == {"lambda_max": land["x"]["values"][best[1]], "epsilon": land["y"]["values"][best[2]]}
    assert 0.0 < land["feasible_fraction"] < 1.0 and land["evaluations"] == 480
    assert land["marks"] == {
        "tuning_job_id": job["id"],
        "ga_optimum": tuned["best_params"],
        "ga_objective_b": tuned["best_objective_b"],
        "dls_objective_b": tuned["dls_baseline"]["objective_b"],
    }
    # a cell is the plan of its parameters
    i, j = best[1], best[2]
    params = {"lambda_max": land["x"]["values"][i], "epsilon": land["y"]["values"][j]}
    one = client.post(
        "/v1/plans",
        params={"fields": ""},
        json={"robot_id": "table1", "task": PAPER_TASK, "method": {"name": "adaptive", "params": params}, "replay": False},
    ).json()
    assert abs(one["metrics"]["objective_b"] - best[0]) <= 1e-12 * best[0]

    assert client.get(land["links"]["self"]).json() == land
    svg = client.get(land["links"]["heatmap"])
    assert svg.status_code == 200 and svg.headers["content-type"].startswith("image/svg+xml")
    for label in ("lambda_max", "epsilon", "infeasible", "GA optimum", "B of the tuned DLS", "log10 B"):
        assert label in svg.text, label
    png = client.get(land["links"]["heatmap"], params={"format": "png"})
    assert png.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert client.delete(land["links"]["self"]).status_code == 204
    assert client.get(land["links"]["self"]).status_code == 404
    assert client.get(land["links"]["heatmap"]).status_code == 404
    assert client.delete(land["links"]["self"]).status_code == 404


def _field(r: httpx.Response) -> str:
    assert r.status_code == 422, r.text
    return str(r.json()["errors"][0]["field"])


def test_landscape_errors_name_the_field(client: httpx.Client) -> None:
    assert _field(client.post("/v1/landscapes", json=landscape_body(x={"name": "lam", "min": 0.0, "max": 0.1}))) == "body.x.name"
    assert (
        _field(client.post("/v1/landscapes", json=landscape_body(y={"name": "lambda_max", "min": 0.0, "max": 0.1})))
        == "body.y.name"
    )
    assert (
        _field(client.post("/v1/landscapes", json=landscape_body(x={"name": "lambda_max", "min": -1.0, "max": 0.1})))
        == "body.x.min"
    )
    log_at_zero = {"name": "epsilon", "min": 0.0, "max": 1.0, "scale": "log"}
    assert _field(client.post("/v1/landscapes", json=landscape_body(y=log_at_zero))) == "body.y.min"
    assert (
        _field(client.post("/v1/landscapes", json=landscape_body(x={"name": "lambda_max", "min": 0.2, "max": 0.1})))
        == "body.x.max"
    )
    # a bound beyond the parameter's range: that bound is named, with its value, not the axis's 32 values
    beyond = client.post("/v1/landscapes", json=landscape_body(x={"name": "lambda_max", "min": 0.0, "max": 100.0}))
    assert _field(beyond) == "body.x.max" and beyond.json()["errors"][0]["message"] == "must be in [0.0, 10.0], got 100.0"
    too_fine = {"name": "lambda_max", "min": 0.0, "max": 0.1, "steps": 129}
    assert _field(client.post("/v1/landscapes", json=landscape_body(x=too_fine))) == "body.x.steps"
    assert _field(client.post("/v1/landscapes", json=landscape_body(method="dls"))) == "body.method"
    assert _field(client.post("/v1/landscapes", json=landscape_body(fixed={"nu": 1.0}))) == "body.fixed.nu"
    axis_fixed = client.post("/v1/landscapes", json=landscape_body(fixed={"lambda_max": 0.05}))
    assert _field(axis_fixed) == "body.fixed.lambda_max" and "adaptive has none besides" in axis_fixed.text
    unknown_job = client.post("/v1/landscapes", json=landscape_body(tuning_job_id="0" * 32))
    assert _field(unknown_job) == "body.tuning_job_id" and "does not exist" in unknown_job.text
    queued = client.post("/v1/tuning-jobs", json=job_body(population=400, generations=200)).json()["id"]
    not_done = client.post("/v1/landscapes", json=landscape_body(tuning_job_id=queued))
    assert _field(not_done) == "body.tuning_job_id"
    client.post(f"/v1/tuning-jobs/{queued}/cancel")
    # the work bound: 128 x 128 cells of a 2,000-step task is 2e8 joint-steps
    big = landscape_body(
        tasks=[{**PAPER_TASK, "dt_s": 0.0075}],
        x={"name": "lambda_max", "min": 0.001, "max": 0.2, "steps": 128},
        y={"name": "epsilon", "min": 0.001, "max": 1.0, "steps": 128},
    )
    r = client.post("/v1/landscapes", json=big)
    assert _field(r) == "body" and re.search(r"^body: the grid is .*joint-steps .* more than 2e\+07", r.json()["detail"])
    assert client.get(f"/v1/landscapes/{'0' * 32}").status_code == 404
