"""A worker spreading GA evaluation over a Dask cluster (SPACEARM_DASK_SCHEDULER)."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from tests.service.conftest import Stack, job_body, wait_status


def test_worker_spreads_generations_over_a_dask_cluster(make_stack: Callable[..., Stack]) -> None:
    distributed = pytest.importorskip("distributed")
    stack = make_stack()
    stack.start_api()
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        stack.client() as client,
    ):
        local = client.post("/v1/tuning-jobs", json=job_body(population=6, generations=3)).json()["id"]
        worker = stack.start_worker()
        local_done = wait_status(client, local, ("succeeded", "failed"))
        worker.stop()
        spread = client.post("/v1/tuning-jobs", json=job_body(population=6, generations=3)).json()["id"]
        dask_worker = stack.start_worker(SPACEARM_DASK_SCHEDULER=cluster.scheduler_address, SPACEARM_DASK_CHUNKS="3")
        spread_done = wait_status(client, spread, ("succeeded", "failed"))
        assert local_done["status"] == spread_done["status"] == "succeeded"
        a = client.get(f"/v1/tuning-jobs/{local}/result").json()
        b = client.get(f"/v1/tuning-jobs/{spread}/result").json()
        # Same seed, same request: the cluster changes where plans run, not the result.
        assert a["best_params"] == b["best_params"] and a["history"] == b["history"]
        # The chunks really ran on the cluster's workers.
        assert "evaluate_chunk" in cluster.scheduler.task_prefixes
        assert "Dask cluster" in dask_worker.log.read_text()
