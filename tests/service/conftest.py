"""Service tests run over real HTTP: uvicorn and worker subprocesses (``python -m service``) on
free loopback ports, each stack with its own SQLite file (or a given database URL, e.g. PostgreSQL)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]

PAPER_TASK: dict[str, Any] = {
    "q0_deg": [175.0, -60.0, -60.0, 0.0, 210.0, 5.0],
    "target_position_m": [1.5, 0.0, -0.2],
    "target_attitude_quaternion": [0.129621343875, 0.001982666841, 0.991518633125, -0.009229106657],
    "duration_s": 15.0,
    "ramp_time_s": 1.5,
    "dt_s": 0.25,
    "profile": "trapezoidal",
    "joint_speed_limit_deg_s": 6.0,
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Proc:
    """A ``python -m service ...`` subprocess with its log file."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path, prefix: tuple[str, ...] = ()) -> None:
        self.args = args
        self.log = log
        self._fh = log.open("ab")
        self.popen = subprocess.Popen(
            [*prefix, sys.executable, "-m", "service", *args], cwd=ROOT, env=env, stdout=self._fh, stderr=subprocess.STDOUT
        )

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5)
        self._fh.close()
        return int(self.popen.returncode)


class Stack:
    """One database (a SQLite file unless ``database_url`` is given) with an API process and any
    number of workers."""

    def __init__(self, directory: Path, lease_seconds: float = 5.0, database_url: str | None = None) -> None:
        self.dir = directory
        self.db_path = directory / "spacearm.db"
        self.database_url = database_url or f"sqlite:///{self.db_path}"
        self.env = {
            **os.environ,
            "SPACEARM_DATABASE_URL": self.database_url,
            "SPACEARM_WORKER_POLL_SECONDS": "0.1",
            "SPACEARM_JOB_LEASE_SECONDS": str(lease_seconds),
            "PYTHONUNBUFFERED": "1",
        }
        self.api: Proc | None = None
        self.port = 0
        self.workers: list[Proc] = []
        self._n = 0
        subprocess.run([sys.executable, "-m", "service", "migrate"], cwd=ROOT, env=self.env, check=True, capture_output=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start_api(self, prefix: tuple[str, ...] = ()) -> None:
        """Start the API (``prefix``: a command it runs under, e.g. one that drops privileges)."""
        self.port = free_port()
        self.api = Proc(["serve", "--host", "127.0.0.1", "--port", str(self.port)], self.env, self.dir / "api.log", prefix)
        # Ready for tests once it answers and its kernels are in (the database may be at any state).
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            try:
                if httpx.get(self.url + "/readyz", timeout=1).json().get("kernels") == "ok":
                    return
            except (httpx.HTTPError, ValueError):
                pass
            if self.api.popen.poll() is not None:
                break
            time.sleep(0.1)
        raise RuntimeError("API did not start:\n" + (self.dir / "api.log").read_text())

    def stop_api(self) -> None:
        if self.api is not None:
            self.api.stop()
            self.api = None

    def start_worker(self, **env: str) -> Proc:
        self._n += 1
        proc = Proc(["worker"], {**self.env, **env}, self.dir / f"worker{self._n}.log")
        self.workers.append(proc)
        return proc

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=60)

    def close(self) -> None:
        for w in self.workers:
            w.stop()
        self.stop_api()


@pytest.fixture
def make_stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Callable[..., Stack]]:
    stacks: list[Stack] = []

    def make(lease_seconds: float = 5.0, database_url: str | None = None) -> Stack:
        stack = Stack(tmp_path_factory.mktemp("stack"), lease_seconds, database_url)
        stacks.append(stack)
        return stack

    yield make
    for s in stacks:
        s.close()


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    """API and one worker, shared by a test module."""
    s = Stack(tmp_path_factory.mktemp("stack"))
    s.start_api()
    s.start_worker()
    yield s
    s.close()


@pytest.fixture
def client(stack: Stack) -> Iterator[httpx.Client]:
    with stack.client() as c:
        yield c


def wait_for(fn: Callable[[], Any], timeout: float = 30.0, interval: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = fn()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting")
        time.sleep(interval)


def wait_status(client: httpx.Client, job_id: str, statuses: tuple[str, ...], timeout: float = 60.0) -> dict[str, Any]:
    def check() -> dict[str, Any] | None:
        job = client.get(f"/v1/tuning-jobs/{job_id}").json()
        return job if job["status"] in statuses else None

    result: dict[str, Any] = wait_for(check, timeout)
    return result


def job_body(population: int = 4, generations: int = 2, compare: bool = True, **task: Any) -> dict[str, Any]:
    return {
        "robot_id": "table1",
        "tasks": [{**PAPER_TASK, **task}],
        "method": "adaptive",
        "ga": {"population": population, "generations": generations, "seed": 1},
        "objective": {"weights": [0.5, 0.5], "aggregation": "max"},
        "compare_with_dls": compare,
        "refine": False,  # the paper's GA alone: the job tests count its generations and plans
    }
