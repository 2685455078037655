"""The tuning-job lifecycle and the queue, over HTTP against uvicorn and worker subprocesses."""

from __future__ import annotations

import signal
from collections.abc import Callable

import httpx
import pytest
from sqlalchemy import text

from service.infra.db import make_engine
from service.usecases.tuning_run import job_seed
from tests.service.conftest import PAPER_TASK, Stack, job_body, wait_for, wait_status

# A job long enough to be interrupted (about 0.03 s per generation, 1000 generations, twice).
LONG = job_body(population=20, generations=1000)


def test_job_succeeds_with_result(client: httpx.Client, stack: Stack) -> None:
    r = client.post("/v1/tuning-jobs", json=job_body(population=4, generations=2))
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/tuning-jobs/{job['id']}"
    assert job["status"] in ("queued", "running", "succeeded")
    done = wait_status(client, job["id"], ("succeeded", "failed"))
    assert done["status"] == "succeeded", done
    assert done["attempts"] == 1 and done["error"] is None
    # the worker that ran it, by the id it logs when it starts polling
    (worker,) = stack.workers
    assert f"worker {done['worker_id']} polling" in worker.log.read_text()
    assert done["started_at"] and done["finished_at"]
    assert done["progress"]["generation"] == done["progress"]["generations"] == 4
    assert done["progress"]["best_objective_b"] > 0 and set(done["progress"]["best_params"]) == {"lambda_max", "epsilon"}
    result = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
    assert result["status"] == "succeeded" and result["message"] == "every generation ran"
    assert set(result["best_params"]) == {"lambda_max", "epsilon"}
    assert result["best_objective_b"] == done["progress"]["best_objective_b"]
    assert [h["generation"] for h in result["history"]] == [0, 1, 2]
    assert 0 < result["evaluations"] <= 2 * (4 + 2 * 3)  # two GAs: population + 2 x 3 offspring, repeats cached
    assert result["elapsed_s"] > 0
    assert result["dls_baseline"]["lambda"] > 0 and result["dls_baseline"]["objective_b"] > 0
    assert isinstance(result["improvement_over_dls_percent"], float)
    assert len(result["best_metrics"]) == 1 and result["best_metrics"][0]["joint_speed_limit_respected"]

    assert result["seed"] == 1  # job_body's

    listing = client.get("/v1/tuning-jobs", params={"status": "succeeded"}).json()
    assert job["id"] in [j["id"] for j in listing["items"]]
    assert all(j["status"] == "succeeded" for j in listing["items"])
    assert client.get("/v1/tuning-jobs", params={"status": "bogus"}).status_code == 422
    assert client.post(f"/v1/tuning-jobs/{job['id']}/cancel").status_code == 409


def test_job_without_dls_baseline(client: httpx.Client) -> None:
    job = client.post("/v1/tuning-jobs", json=job_body(population=4, generations=1, compare=False)).json()
    assert wait_status(client, job["id"], ("succeeded", "failed"))["status"] == "succeeded"
    result = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
    assert result["dls_baseline"] is None and result["improvement_over_dls_percent"] is None


def test_job_with_the_bounded_third_row(client: httpx.Client) -> None:
    """With ``compare_with_bounded`` the job runs a third GA, on the bounded inverse, and its result
    is the comparison's third row, checked against the phases' own histories."""
    body = job_body(population=4, generations=1) | {"compare_with_bounded": True}
    job = client.post("/v1/tuning-jobs", json=body).json()
    done = wait_status(client, job["id"], ("succeeded", "failed"))
    assert done["status"] == "succeeded", done
    assert [(p["name"], p["role"]) for p in done["progress"]["phases"]] == [
        ("adaptive", "tuned"),
        ("dls", "dls_baseline"),
        ("bounded", "bounded_baseline"),
    ]
    assert done["progress"]["generations"] == 3  # one generation in each of three GAs
    result = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
    bounded, dls = result["bounded_baseline"], result["dls_baseline"]
    assert bounded["lambda"] > 0 and bounded["objective_b"] > 0
    assert bounded["objective_b"] == done["progress"]["phases"][2]["history"][-1]["best"]
    assert result["bounded_improvement_over_dls_percent"] == pytest.approx(
        100.0 * (dls["objective_b"] - bounded["objective_b"]) / dls["objective_b"], rel=1e-12
    )
    # a job that tunes the bounded inverse itself has no third row
    itself = client.post("/v1/tuning-jobs", json=body | {"method": "bounded", "bounds": None}).json()
    assert wait_status(client, itself["id"], ("succeeded", "failed"))["status"] == "succeeded"
    assert client.get(f"/v1/tuning-jobs/{itself['id']}/result").json()["bounded_baseline"] is None


def test_job_fails_with_error(client: httpx.Client) -> None:
    # a speed limit nobody can respect: every individual is infeasible
    job = client.post("/v1/tuning-jobs", json=job_body(population=4, generations=1, joint_speed_limit_deg_s=0.001)).json()
    failed = wait_status(client, job["id"], ("succeeded", "failed"))
    assert failed["status"] == "failed"
    assert "no feasible parameters" in failed["error"]
    problem = client.get(f"/v1/tuning-jobs/{job['id']}/result")
    assert problem.status_code == 409 and problem.headers["content-type"].startswith("application/problem+json")


def test_cancel_running_and_queued(client: httpx.Client) -> None:
    long_job = client.post("/v1/tuning-jobs", json=LONG).json()
    wait_for(lambda: client.get(f"/v1/tuning-jobs/{long_job['id']}").json()["progress"]["generation"] >= 2)
    queued = client.post("/v1/tuning-jobs", json=job_body()).json()  # the only worker is busy
    r = client.post(f"/v1/tuning-jobs/{queued['id']}/cancel")
    assert r.status_code == 202 and r.json()["status"] == "cancelled"
    assert client.get(f"/v1/tuning-jobs/{queued['id']}/result").status_code == 409
    r = client.post(f"/v1/tuning-jobs/{long_job['id']}/cancel")
    assert r.status_code == 202 and r.json()["cancel_requested"] is True
    cancelled = wait_status(client, long_job["id"], ("cancelled", "succeeded", "failed"), timeout=10)
    assert cancelled["status"] == "cancelled"
    assert cancelled["progress"]["generation"] < 1000
    # it keeps the best found before the cancel: the progress's last best, with the history up to it
    kept = client.get(f"/v1/tuning-jobs/{long_job['id']}/result")
    assert kept.status_code == 200, kept.text
    best = kept.json()
    (tuned, baseline) = cancelled["progress"]["phases"]
    assert best["status"] == "cancelled" and best["dls_baseline"] is None and baseline["completed"] == 0
    assert best["message"].startswith(f"cancelled after generation {tuned['completed']} of 1000 of the adaptive GA")
    assert [h["generation"] for h in best["history"]] == list(range(tuned["completed"] + 1)) and tuned["completed"] >= 2
    assert best["best_objective_b"] == cancelled["progress"]["best_objective_b"] == min(h["best"] for h in tuned["history"])
    assert best["best_params"] == cancelled["progress"]["best_params"]
    (metrics,) = best["best_metrics"]
    assert metrics["objective_b"] == pytest.approx(best["best_objective_b"], rel=1e-9)
    assert client.post("/v1/tuning-jobs/nope/cancel").status_code == 404


def test_job_validation_and_idempotency(client: httpx.Client) -> None:
    assert client.get("/v1/tuning-jobs/nope").status_code == 404
    assert client.get("/v1/tuning-jobs/nope/result").status_code == 404
    bad = client.post("/v1/tuning-jobs", json={**job_body(), "bounds": {"lambda_max": [0.2, 0.1]}})
    assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == "body.bounds.lambda_max"
    bad = client.post("/v1/tuning-jobs", json={**job_body(), "method": "inverse"})
    assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == "body.method"
    bad = client.post("/v1/tuning-jobs", json={**job_body(), "ga": {"population": 1}})
    assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == "body.ga.population"
    bad = client.post("/v1/tuning-jobs", json={**job_body(), "tasks": [{**PAPER_TASK, "q0_deg": [1.0]}]})
    assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == "body.tasks[0].q0_deg"
    assert client.post("/v1/tuning-jobs", json={**job_body(), "robot_id": "nope"}).status_code == 404

    headers = {"Idempotency-Key": "flow-42"}
    first = client.post("/v1/tuning-jobs", json=job_body(), headers=headers)
    second = client.post("/v1/tuning-jobs", json=job_body(), headers=headers)
    assert first.status_code == second.status_code == 202
    assert first.json()["id"] == second.json()["id"]
    assert second.headers["location"] == first.headers["location"]
    wait_status(client, first.json()["id"], ("succeeded",))


def worker_killed_mid_job_another_finishes(stack: Stack) -> None:
    """SIGKILL the worker of a running job; once its lease expires a second worker finishes the
    job, exactly once. ``stack``: lease seconds short, nothing started yet (any database)."""
    stack.start_api()
    first = stack.start_worker()
    with stack.client() as client:
        job = client.post("/v1/tuning-jobs", json=job_body(population=8, generations=60, compare=False)).json()
        wait_for(lambda: client.get(f"/v1/tuning-jobs/{job['id']}").json()["progress"]["generation"] >= 3)
        first.stop(signal.SIGKILL)  # dies without giving the job back
        stalled = client.get(f"/v1/tuning-jobs/{job['id']}").json()
        assert stalled["status"] == "running" and stalled["attempts"] == 1
        stack.start_worker()  # claims the job once the dead worker's lease expired
        done = wait_status(client, job["id"], ("succeeded", "failed"), timeout=60)
        assert done["status"] == "succeeded", done
        assert done["attempts"] == 2
        assert len(client.get(f"/v1/tuning-jobs/{job['id']}/result").json()["history"]) == 61
        assert client.get("/v1/tuning-jobs").json()["total"] == 1  # still one job
    # exactly once: one claim per worker, one final write, by the second worker
    dead, second = (w.log.read_text() for w in stack.workers)
    outcomes = ("succeeded", "failed", "cancelled", "requeued", "lost")
    assert dead.count("claimed") == 1 and not any(f"job {job['id']}: {outcome}" in dead for outcome in outcomes)
    assert second.count("claimed") == 1 and second.count(f"job {job['id']}: succeeded") == 1
    engine = make_engine(stack.database_url)
    try:
        with engine.connect() as conn:
            rows = conn.execute(text("SELECT status, attempts, result IS NOT NULL, lease_owner FROM tuning_jobs")).all()
    finally:
        engine.dispose()
    assert [tuple(r) for r in rows] == [("succeeded", 2, 1, None)]  # PostgreSQL says True: == 1


def test_a_random_seed_is_drawn_once_per_job_and_reported(client: httpx.Client) -> None:
    """``ga.seed`` null: the seed comes from the job's id (every run of the job, a requeued one
    too, runs the same GA), the result reports it, and a job sent with it runs the same GA."""
    body = job_body(population=4, generations=3, compare=False)
    drawn = []
    for _ in range(2):
        job = client.post("/v1/tuning-jobs", json={**body, "ga": {**body["ga"], "seed": None}}).json()
        assert wait_status(client, job["id"], ("succeeded", "failed"))["status"] == "succeeded"
        result = client.get(f"/v1/tuning-jobs/{job['id']}/result").json()
        assert result["seed"] == job_seed(job["id"]), result["seed"]
        drawn.append(result)
    assert drawn[0]["seed"] != drawn[1]["seed"]  # random across jobs
    again = client.post("/v1/tuning-jobs", json={**body, "ga": {**body["ga"], "seed": drawn[0]["seed"]}}).json()
    assert wait_status(client, again["id"], ("succeeded", "failed"))["status"] == "succeeded"
    same = client.get(f"/v1/tuning-jobs/{again['id']}/result").json()
    assert same["seed"] == drawn[0]["seed"]
    assert same["best_params"] == drawn[0]["best_params"] and same["history"] == drawn[0]["history"]


def test_worker_killed_mid_job_another_finishes(make_stack: Callable[..., Stack]) -> None:
    worker_killed_mid_job_another_finishes(make_stack(lease_seconds=1.0))


def test_sigterm_requeues_the_running_job(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack(lease_seconds=30.0)
    stack.start_api()
    worker = stack.start_worker()
    with stack.client() as client:
        job = client.post("/v1/tuning-jobs", json=LONG).json()
        wait_for(lambda: client.get(f"/v1/tuning-jobs/{job['id']}").json()["progress"]["generation"] >= 2)
        assert worker.stop(signal.SIGTERM) == 0
        # stopped inside the generation that was running (the plans see the termination), or
        # right after it: not after the watcher's next look a second later (~30 more generations)
        after_signal = worker.log.read_text().split("stopping after the current generation", 1)[1]
        assert sum("generation" in line for line in after_signal.splitlines() if f"job {job['id']}:" in line) <= 1, after_signal
        back = client.get(f"/v1/tuning-jobs/{job['id']}").json()
        assert back["status"] == "queued" and back["attempts"] == 0
        # a new worker takes it at once (no lease to wait for); cancel it to finish quickly
        stack.start_worker()
        wait_status(client, job["id"], ("running",))
        client.post(f"/v1/tuning-jobs/{job['id']}/cancel")
        assert wait_status(client, job["id"], ("cancelled",))["attempts"] == 1


def two_workers_share_the_queue(stack: Stack, jobs: int = 6) -> list[str]:
    """Two workers, then ``jobs`` submitted: every job succeeds after exactly one claim and both
    workers take part. Returns the job ids. ``stack``: API started, no workers yet."""
    workers = [stack.start_worker(), stack.start_worker()]
    wait_for(lambda: all("polling" in w.log.read_text() for w in workers))  # both up: neither drains the queue alone
    with stack.client() as client:
        ids = [client.post("/v1/tuning-jobs", json=job_body(population=6, generations=10)).json()["id"] for _ in range(jobs)]
        for job_id in ids:
            done = wait_status(client, job_id, ("succeeded", "failed"), timeout=60)
            assert done["status"] == "succeeded" and done["attempts"] == 1
    logs = [w.log.read_text() for w in stack.workers]
    for job_id in ids:  # every job claimed exactly once, by one worker
        assert sum(log.count(f"job {job_id} claimed") for log in logs) == 1
    claimed = [log.count("claimed") for log in logs]
    assert sum(claimed) == jobs
    assert all(c >= 1 for c in claimed), claimed  # both workers took part
    return ids


def test_two_workers_share_the_queue(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.start_api()
    two_workers_share_the_queue(stack)


def test_data_survives_api_restart(make_stack: Callable[..., Stack]) -> None:
    stack = make_stack()
    stack.start_api()
    with stack.client() as client:
        robot = client.get("/v1/robots/table1").json()["parameters"]
        created = client.post("/v1/robots", json={**robot, "name": "kept"}).json()
        plan = client.post("/v1/plans", json={"robot_id": "table1", "task": PAPER_TASK, "replay": False}).json()
        job = client.post("/v1/tuning-jobs", json=job_body()).json()
    stack.stop_api()
    stack.start_api()
    with stack.client() as client:
        assert client.get(f"/v1/robots/{created['id']}").json()["name"] == "kept"
        assert client.get(f"/v1/plans/{plan['id']}").json()["metrics"] == plan["metrics"]
        assert client.get(f"/v1/tuning-jobs/{job['id']}").json()["status"] == "queued"
        assert client.get("/readyz").status_code == 200
