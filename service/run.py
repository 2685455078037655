"""``spacearm run`` (what ``make run`` calls): the API and its workers as child processes, the URL
printed once ``/readyz`` answers, Ctrl-C (or SIGTERM) passed on to both.

The children run in process groups of their own, so a Ctrl-C in the terminal reaches only this
process, which sends each child one SIGTERM (uvicorn would take a second signal as "exit now"
without finishing requests; a worker puts its job back in the queue). On Linux they also get
SIGTERM if this process dies without that chance (``PR_SET_PDEATHSIG``)."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx

from service.infra.logs import Say

PR_SET_PDEATHSIG = 1
logging.getLogger("httpx").setLevel(logging.WARNING)  # our /readyz polls are in the API's access log
STOP_TIMEOUT_S = 30.0  # a worker finishes its generation, uvicorn its requests


def local_url(host: str, port: int) -> str:
    """The URL this machine reaches an API bound to ``host`` at (a wildcard address: loopback)."""
    host = {"0.0.0.0": "127.0.0.1", "": "127.0.0.1", "::": "::1"}.get(host, host)
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    if sys.platform == "linux":
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def start(args: list[str], env: dict[str, str]) -> subprocess.Popen[bytes]:
    """``python -P -m service <args>`` in a process group of its own, sharing our stdout/stderr.
    ``-P``: the installed package, not a source tree that happens to be the working directory (the
    image's /app): numba keys its kernel cache by source path, so that would recompile them."""
    command = [sys.executable, "-P", "-m", "service", *args]
    return subprocess.Popen(command, env=env, process_group=0, preexec_fn=_die_with_parent)


def migrate_in_child(env: dict[str, str], *, verbose: bool = False) -> int:
    """``spacearm migrate`` in a child process (sharing our stdout/stderr); its exit code."""
    command = [sys.executable, "-P", "-m", "service", "migrate", *(["--verbose"] if verbose else [])]
    return subprocess.run(command, env=env, check=False, preexec_fn=_die_with_parent).returncode


def wait_ready(url: str, alive: Callable[[], str | None], stop: threading.Event, timeout_s: float, say: Say) -> str | None:
    """Poll ``url/readyz`` until it answers 200. Returns None once ready, else why not: a child
    that died (``alive()`` says which), a stop request, or the time limit with the last answer."""
    start = time.monotonic()
    deadline = start + timeout_s
    last = "no answer yet"
    interval = 0.1  # growing to 1 s: each poll is a line of the API's access log
    told = False
    with httpx.Client(timeout=5.0) as client:
        while True:
            dead = alive()
            if dead is not None:
                return dead
            if stop.is_set():
                return "stopped before the API was ready"
            try:
                response = client.get(url + "/readyz")
                if response.status_code == 200:
                    return None
                last = f"{response.status_code} {response.text.strip()}"
            except httpx.HTTPError as exc:
                last = f"{type(exc).__name__}"
            if time.monotonic() > deadline:
                return f"the API was not ready within {timeout_s:g} s (last /readyz answer: {last})"
            if not told and time.monotonic() - start > 10.0:
                say("spacearm run: waiting for the API (a first run compiles the kernels: about a minute)", False)
                told = True
            stop.wait(interval)
            interval = min(1.0, 1.5 * interval)


def run(host: str, port: int, workers: int, ready_timeout_s: float, env: dict[str, str], say: Say) -> int:
    """Start the API on ``host:port`` and ``workers`` workers; say the URL once ready; return
    when stopped (0) or when a child exits on its own (1)."""
    stop = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    children: dict[str, subprocess.Popen[bytes]] = {}
    try:
        children["API"] = start(["serve", "--host", host, "--port", str(port)], env)
        for i in range(workers):
            children[f"worker {i + 1}" if workers > 1 else "worker"] = start(["worker"], env)

        def exited() -> str | None:
            for name, child in children.items():
                if child.poll() is not None:
                    return f"the {name} process exited with code {child.returncode}"
            return None

        url = local_url(host, port)
        problem = wait_ready(url, exited, stop, ready_timeout_s, say)
        if problem is not None:
            if stop.is_set():
                return 0
            say(f"spacearm run: {problem} (see its log above); stopping", True)
            return 1
        where = f"{url} (docs at {url}/docs, metrics at {url}/metrics)"
        say(f"spacearm API on {where}, {workers} worker(s); Ctrl-C stops them", False)
        while not stop.wait(0.5):
            problem = exited()
            if problem is not None:
                say(f"spacearm run: {problem}; stopping", True)
                return 1
        return 0
    finally:
        _stop_all(children)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _stop_all(children: dict[str, subprocess.Popen[bytes]]) -> None:
    for child in children.values():
        if child.poll() is None:
            child.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    for child in children.values():
        try:
            child.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def child_env(log_format: str, log_level: str) -> dict[str, str]:
    """Our environment with the logging options passed on."""
    return {**os.environ, "SPACEARM_LOG_FORMAT": log_format, "SPACEARM_LOG_LEVEL": log_level}
