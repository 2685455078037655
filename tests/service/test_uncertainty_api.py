"""Uncertainty over the API (issue 20): a plan's robustness (as the engine computes it, stored,
listed and drawn), 422s naming the uncertainty's fields, and a robust tuning job end to end with
its nominal tuning, the refinement's records and the robust figures."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from engine import make_inverse, paper_task, run_plan, table1_robot
from engine.planner import PlanSetup
from engine.robustness import robustness
from engine.trajectory import PAPER_TASK_PARAMS
from engine.uncertainty import Uncertainty
from tests.service.conftest import PAPER_TASK, job_body, wait_status

TUNED = {"name": "adaptive", "params": PAPER_TASK_PARAMS["adaptive"]}
UNCERTAINTY = {"carrier_mass_rel": 0.1, "carrier_inertia_rel": 0.1, "samples": 16, "seed": 4}


def _fields(r: httpx.Response) -> list[str]:
    assert r.status_code == 422, r.text
    return [e["field"] for e in r.json().get("errors") or []]


def test_a_plan_under_uncertainty_carries_its_robustness(client: httpx.Client) -> None:
    body = {"robot_id": "table1", "task": PAPER_TASK, "method": TUNED, "replay": False, "uncertainty": UNCERTAINTY}
    r = client.post("/v1/plans", json=body)
    assert r.status_code == 201, r.text
    created = r.json()
    model = table1_robot()
    setup = PlanSetup(model, paper_task(model))
    inverse = make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"])
    expected = robustness(setup, inverse, run_plan(setup, inverse), Uncertainty(0.1, 0.1, samples=16, seed=4))
    got = created["robustness"]
    assert got["samples"] == 16 and got["success"] is expected.success
    for name, loop in (("open_loop", expected.open_loop), ("closed_loop", expected.closed_loop)):
        assert got[name]["position_error_max_m"] == pytest.approx(loop.position_error_max.as_dict(), rel=1e-9)
        assert got[name]["worst_sample"]["index"] == loop.worst_index
        assert got[name]["worst_sample"]["carrier_mass_factor"] == pytest.approx(loop.worst.carrier_mass_factor, rel=1e-12)
        assert got[name]["limit_broken_fraction"] == loop.limit_broken_fraction
    stored = client.get(f"/v1/plans/{created['id']}", params={"fields": ""}).json()
    assert stored["robustness"] == got and stored["request"]["uncertainty"]["samples"] == 16
    listed = client.get("/v1/plans", params={"limit": 1}).json()["items"][0]
    assert listed["id"] == created["id"] and listed["robustness"] == got
    figure = client.get(f"/v1/plans/{created['id']}/figures/robustness")
    assert figure.status_code == 200 and figure.headers["content-type"].startswith("image/svg+xml")
    assert b"closed loop" in figure.content
    nominal = client.post("/v1/plans", json={**body, "uncertainty": None}).json()
    assert nominal["robustness"] is None and nominal["metrics"] == created["metrics"]  # the nominal plan is unchanged
    assert client.get(f"/v1/plans/{nominal['id']}/figures/robustness").status_code == 200  # says there are no samples


def test_an_invalid_uncertainty_is_a_422_naming_its_field(client: httpx.Client) -> None:
    base = {"robot_id": "table1", "task": PAPER_TASK, "method": TUNED, "replay": False}
    cases = [
        ({"carrier_mass_rel": 0.4, "distribution": "normal"}, "body.uncertainty.carrier_mass_rel"),  # 1 - 3 x 0.4 < 0
        ({"link_mass_rel": 1.0}, "body.uncertainty.link_mass_rel"),
        ({"samples": 1025}, "body.uncertainty.samples"),
        ({"q0_deg": -1.0}, "body.uncertainty.q0_deg"),
        ({"distribution": "cauchy"}, "body.uncertainty.distribution"),
    ]
    for uncertainty, field in cases:
        assert field in _fields(client.post("/v1/plans", json={**base, "uncertainty": uncertainty})), uncertainty
    # more samples than a synchronous plan may cost: 20,000 steps x 2 loops x 6 joints each
    long_task = {**PAPER_TASK, "dt_s": 15.0 / 20000}
    r = client.post("/v1/plans", json={**base, "task": long_task, "uncertainty": {"samples": 64}})
    assert _fields(r) == ["body.uncertainty.samples"] and "at most 20 samples" in r.text
    job = {**job_body(), "uncertainty": {"samples": 1024}, "ga": {"population": 100, "generations": 100, "seed": 1}}
    assert "body.uncertainty.samples" in _fields(client.post("/v1/tuning-jobs", json=job))


def test_a_robust_tuning_job_reports_robust_and_nominal_b(client: httpx.Client) -> None:
    body: dict[str, Any] = {
        **job_body(population=4, generations=2),
        "uncertainty": {"carrier_mass_rel": 0.1, "carrier_inertia_rel": 0.1, "samples": 4},
        "robust_statistic": "max",
        "refine": True,
    }
    r = client.post("/v1/tuning-jobs", json=body)
    assert r.status_code == 202, r.text
    done = wait_status(client, r.json()["id"], ("succeeded", "failed"), timeout=120)
    assert done["status"] == "succeeded", done
    roles = [p["role"] for p in done["progress"]["phases"]]
    assert roles == ["tuned", "dls_baseline", "nominal_tuned"]
    assert done["progress"]["generation"] == done["progress"]["generations"] == 6
    tuned_history = done["progress"]["phases"][0]["history"]
    assert {h["stage"] for h in tuned_history} == {"ga", "refine"}
    result = client.get(f"/v1/tuning-jobs/{done['id']}/result").json()
    robust = result["robust"]
    assert robust["samples"] == 4 and robust["statistic"] == "max"
    assert robust["tuned"]["objective_b"] == result["best_objective_b"] <= result["ga_objective_b"]
    assert robust["tuned"]["nominal_objective_b"] > 0 and robust["dls_baseline"]["objective_b"] > 0
    nominal = robust["nominal_tuning"]
    assert set(nominal["best_params"]) == {"lambda_max", "epsilon"} and nominal["nominal_objective_b"] > 0
    if nominal["objective_b"] is None:  # the nominal optimum breaks a limit on some sample (it sits on the speed limit)
        assert robust["improvement_over_nominal_tuning_percent"] is None
    else:
        assert robust["improvement_over_nominal_tuning_percent"] == pytest.approx(
            100 * (nominal["objective_b"] - robust["tuned"]["objective_b"]) / nominal["objective_b"]
        )
    assert [h["stage"] for h in result["history"]].count("ga") == 3
