"""HTTP benchmark: `POST /v1/plans` of the paper task against a live server, p50/p95 latency and
plans per second with 1, 4 and 16 concurrent clients, replay false and true; the ratio of the
replay-true p50 to the replay-false p50 (target: at most 2), and the first request after the
server says it is ready against the steady state (target: at most 2). Then reads with one
client: `GET /v1/plans/{id}` of a stored paper plan, whole and summary only (`fields=`), and
`GET /healthz` for scale.

Run: `.venv/bin/python bench/bench_http.py` (starts its own API on a temporary SQLite file) or
`.venv/bin/python bench/bench_http.py --url http://127.0.0.1:8000` against a running server;
`--processes 2`: two API processes behind the port (``spacearm run --api-processes 2``). Each row
also gives the server's CPU time per plan (all its processes; the GIL-bound share of it bounds
what one process can serve) and the clients' (this process).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx

from service.schemas.common import PAPER_TASK_EXAMPLE

ROOT = Path(__file__).resolve().parents[1]


def body(replay: bool) -> dict[str, Any]:
    return {
        "robot_id": "table1",
        "task": PAPER_TASK_EXAMPLE,
        "method": {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}},
        "replay": replay,
    }


def start_server(directory: Path, processes: int = 1) -> tuple[subprocess.Popen[bytes], str]:
    """An API on a temporary SQLite file: ``spacearm serve``, or with ``processes`` > 1 ``spacearm
    run --api-processes N`` without workers (the processes behind one port)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "SPACEARM_DATABASE_URL": f"sqlite:///{directory / 'bench.db'}"}
    env.pop("PROMETHEUS_MULTIPROC_DIR", None)
    subprocess.run([sys.executable, "-m", "service", "migrate"], cwd=ROOT, env=env, check=True, capture_output=True)
    log = (directory / "api.log").open("wb")
    command = ["serve", "--port", str(port)]
    if processes > 1:
        command = ["run", "--port", str(port), "--workers", "0", "--api-processes", str(processes)]
    proc = subprocess.Popen([sys.executable, "-m", "service", *command], cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        try:
            if httpx.get(url + "/readyz", timeout=1).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError("the API did not become ready")


def cpu_seconds(pid: int) -> float:
    """CPU time (user and system) of process ``pid`` and its descendants so far, s (Linux)."""
    total = 0.0
    with contextlib.suppress(OSError):
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        for task in Path(f"/proc/{pid}/task").iterdir():
            for child in (task / "children").read_text().split():
                total += cpu_seconds(int(child))
    return total


def run(url: str, clients: int, per_client: int, replay: bool) -> tuple[list[float], float]:
    latencies: list[float] = []
    lock = threading.Lock()
    payload = json.dumps(body(replay))

    def client() -> None:
        with httpx.Client(base_url=url, timeout=120) as c:
            for _ in range(per_client):
                start = time.perf_counter()
                r = c.post("/v1/plans", content=payload, headers={"content-type": "application/json"})
                elapsed = time.perf_counter() - start
                if r.status_code != 201:
                    raise RuntimeError(f"{r.status_code}: {r.text[:300]}")
                with lock:
                    latencies.append(elapsed)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return latencies, time.perf_counter() - start


def reads(url: str, proc: subprocess.Popen[bytes] | None, requests: int) -> None:
    """p50 and the server's CPU per request of reads with one client (kept-alive connection)."""
    with httpx.Client(base_url=url, timeout=120) as c:
        plan = c.post("/v1/plans", json=body(False))
        plan.raise_for_status()
        path = f"/v1/plans/{plan.json()['id']}"
        paths = {"GET plan": path, "GET plan fields=": f"{path}?fields=", "GET /healthz": "/healthz"}
        print(f"{'read':>18} {'p50 ms':>8} {'server CPU ms':>14}")
        for name, path in paths.items():
            for _ in range(10):
                c.get(path).raise_for_status()
            server_cpu = cpu_seconds(proc.pid) if proc else math.nan
            latencies = []
            for _ in range(requests):
                start = time.perf_counter()
                c.get(path).raise_for_status()
                latencies.append(time.perf_counter() - start)
            server_cpu = (cpu_seconds(proc.pid) if proc else math.nan) - server_cpu
            print(f"{name:>18} {statistics.median(latencies) * 1e3:8.2f} {server_cpu / requests * 1e3:14.2f}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--url", help="a running server; otherwise one is started on a temporary database")
    parser.add_argument("--requests", type=int, default=48, help="requests per scenario")
    parser.add_argument("--processes", type=int, default=1, help="API processes behind the port (spacearm run --api-processes)")
    args = parser.parse_args()
    proc = None
    tmp = tempfile.TemporaryDirectory()
    url = args.url
    if url is None:
        proc, url = start_server(Path(tmp.name), args.processes)
    try:
        first, _ = run(url, 1, 1, True)  # the first request after /readyz
        run(url, 2, 4, True)  # warm-up: connections, caches
        print(f"POST /v1/plans, paper task, {args.requests} requests per scenario against {url}")
        # the server's CPU per plan (all its processes), and this process's (the clients')
        heads = ("replay", "clients", "p50 ms", "p95 ms", "plans/s", "server CPU ms", "client CPU ms")
        print(" ".join(f"{h:>{w}}" for h, w in zip(heads, (6, 7, 8, 8, 8, 14, 14), strict=True)))
        p50 = {}
        for replay in (False, True):
            for clients in (1, 4, 16):
                server_cpu, client_cpu = cpu_seconds(proc.pid) if proc else math.nan, time.process_time()
                latencies, wall = run(url, clients, max(1, args.requests // clients), replay)
                server_cpu = (cpu_seconds(proc.pid) if proc else math.nan) - server_cpu
                client_cpu = time.process_time() - client_cpu
                q = statistics.quantiles(latencies, n=20)
                median = p50[(replay, clients)] = statistics.median(latencies)
                n = len(latencies)
                print(
                    f"{replay!s:>6} {clients:7d} {median * 1e3:8.1f} {q[18] * 1e3:8.1f} {n / wall:8.1f} "
                    f"{server_cpu / n * 1e3:14.2f} {client_cpu / n * 1e3:14.2f}"
                )
        print(f"replay true / replay false, p50 with one client: {p50[(True, 1)] / p50[(False, 1)]:.2f} (target <= 2)")
        print(
            f"first request after /readyz (replay true): {first[0] * 1e3:.1f} ms, "
            f"{first[0] / p50[(True, 1)]:.2f}x the steady-state p50 (target <= 2)"
        )
        reads(url, proc, args.requests)
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(10)
        tmp.cleanup()


if __name__ == "__main__":
    main()
