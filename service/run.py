"""``spacearm run`` (what ``make run`` calls): the API and its workers as child processes, the URL
printed once ``/readyz`` answers, Ctrl-C (or SIGTERM) passed on to both.

The children run in process groups of their own, so a Ctrl-C in the terminal reaches only this
process, which sends each child one SIGTERM (uvicorn would take a second signal as "exit now"
without finishing requests; a worker puts its job back in the queue). On Linux they also get
SIGTERM if this process dies without that chance (``PR_SET_PDEATHSIG``)."""

from __future__ import annotations

import contextlib
import ctypes
import importlib.util
import logging
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

from service.infra.logs import Say

PR_SET_PDEATHSIG = 1
logging.getLogger("httpx").setLevel(logging.WARNING)  # our /readyz polls are in the API's access log
STOP_TIMEOUT_S = 30.0  # a worker finishes its generation, uvicorn its requests
#: The environment variable naming the file descriptor the API writes its readiness to.
READY_FD = "SPACEARM_READY_FD"
#: How much lower the workers' CPU priority is than the API's (``nice``): on a shared machine a GA
#: generation yields to requests and ``/healthz``, and at start-up the API's imports go first.
WORKER_NICENESS = 5
#: prometheus-client's multiprocess directory (:data:`service.infra.metrics.MULTIPROCESS_DIR`; not
#: imported from there: the launcher imports no prometheus-client, SQLAlchemy or engine).
MULTIPROCESS_DIR = "PROMETHEUS_MULTIPROC_DIR"
#: The setting that tells each API process how many share the port (binding with SO_REUSEPORT).
API_PROCESSES = "SPACEARM_API_PROCESSES"
#: The environment variable naming the file descriptor a child waits on before it starts.
GATE_FD = "SPACEARM_START_GATE_FD"
#: The environment variable naming the file descriptor ``spacearm compile`` writes a line to as
#: each of its parts ends (:func:`prepare_in_children`).
PROGRESS_FD = "SPACEARM_COMPILE_PROGRESS_FD"
#: How many processes ``spacearm compile`` runs at once (``engine.warmup.PARTS``; not imported:
#: the launcher imports no engine), each on a core of its own.
COMPILE_PARTS = 2


def spare_core_while_compiling() -> bool:
    """Whether this process may use more cores than ``spacearm compile``'s parts take."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return usable > COMPILE_PARTS


def local_url(host: str, port: int) -> str:
    """The URL this machine reaches an API bound to ``host`` at (a wildcard address: loopback)."""
    host = {"0.0.0.0": "127.0.0.1", "": "127.0.0.1", "::": "::1"}.get(host, host)
    return f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    if sys.platform == "linux":
        ctypes.CDLL(None).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _worker_child() -> None:  # pragma: no cover - runs in the child between fork and exec
    _die_with_parent()
    os.nice(WORKER_NICENESS)


def start(args: list[str], env: dict[str, str], pass_fds: tuple[int, ...] = (), *, nice: bool = False) -> subprocess.Popen[bytes]:
    """``python -P -m service <args>`` in a process group of its own, sharing our stdout/stderr
    (and the file descriptors ``pass_fds``). ``-P``: the installed package, not a source tree
    that happens to be the working directory (the image's /app): numba keys its kernel cache by
    source path, so that would recompile them."""
    command = [sys.executable, "-P", "-m", "service", *args]
    setup = _worker_child if nice else _die_with_parent
    return subprocess.Popen(command, env=env, process_group=0, preexec_fn=setup, pass_fds=pass_fds)


def kernels_compiled() -> bool:
    """Whether the engine's kernel cache is complete for this CPU, read by
    :mod:`engine.kernels.cache` loaded from its file: the ``engine`` package (numpy, numba) is not
    imported."""
    spec = importlib.util.find_spec("engine")  # a top-level package: found, not imported
    if spec is None or not spec.submodule_search_locations:
        return False
    path = Path(next(iter(spec.submodule_search_locations))) / "kernels" / "cache.py"
    cache_spec = importlib.util.spec_from_file_location("spacearm_kernel_cache", path)
    if cache_spec is None or cache_spec.loader is None:
        return False
    module = importlib.util.module_from_spec(cache_spec)
    cache_spec.loader.exec_module(module)
    return bool(module.compiled())


def prepare_in_children(
    env: dict[str, str],
    stop: threading.Event,
    *,
    verbose: bool = False,
    compile: bool | None = None,
    on_first_part: Callable[[], None] | None = None,
) -> int:
    """``spacearm migrate`` and, unless the kernel cache is complete (``compile``: None asks
    :func:`kernels_compiled`), ``spacearm compile`` in child processes side by side (sharing our
    stdout/stderr): the database at head and the kernels in their cache before the API and the
    workers go on, which then load the kernels in a second instead of each compiling them.
    ``on_first_part`` is called (at most once) when the first of the compilation's parts ends (it
    says so through a pipe, :data:`PROGRESS_FD`), and so a core is free again. Returns 0, the exit code of
    the first that failed (the other is stopped), or 130 if ``stop`` was set."""
    base = [sys.executable, "-P", "-m", "service"]
    # The migration seeds the preset robots a database lacks (a new one: all), so that the API and
    # the workers, which would otherwise, do not build the URDF presets: their parser and trimesh
    # stay in a process, about 60 MiB. It imports the engine only then.
    children: list[subprocess.Popen[bytes]] = []
    progress = -1

    def told() -> None:  # the compilation's first line (or its end: the pipe closed), once
        nonlocal progress
        if progress >= 0 and select.select([progress], [], [], 0)[0]:
            said = os.read(progress, 64)
            os.close(progress)
            progress = -1
            if said and on_first_part is not None:
                on_first_part()

    try:
        children.append(
            subprocess.Popen([*base, "migrate", *(["--verbose"] if verbose else [])], env=env, preexec_fn=_die_with_parent)
        )
        if (not kernels_compiled()) if compile is None else compile:
            progress, written = os.pipe()
            try:
                compiling = {**env, PROGRESS_FD: str(written)}
                command = [*base, "compile"]
                children.append(subprocess.Popen(command, env=compiling, preexec_fn=_die_with_parent, pass_fds=(written,)))
            finally:
                os.close(written)
        while not stop.is_set():
            codes = [child.poll() for child in children]
            told()
            failed = [code for code in codes if code]
            if failed or all(code == 0 for code in codes):
                return failed[0] if failed else 0
            stop.wait(0.05)
        return 130
    finally:
        if progress >= 0:
            os.close(progress)
        for child in children:
            if child.poll() is None:
                child.terminate()
            child.wait()


def pass_gate() -> bool:
    """In a child started by :func:`run`: wait (after the imports, which overlap the migration and
    the compilation) until the launcher says go through the pipe named by :data:`GATE_FD`. False
    if it said no or went away; True at once when there is no gate (``spacearm serve`` or
    ``spacearm worker`` started by hand)."""
    fd = os.environ.pop(GATE_FD, "")
    if not fd.isdigit():
        return True
    received = b""
    with contextlib.suppress(OSError):
        while not received.endswith(b"\n"):
            chunk = os.read(int(fd), 16)
            if not chunk:
                break
            received += chunk
        os.close(int(fd))
    return received == b"go\n"


def notify_ready(text: str) -> None:
    """In the API started by :func:`run`: tell the launcher that the start-up ended (``ready``, or
    why not), through the pipe named by :data:`READY_FD`; nothing when there is none."""
    fd = os.environ.pop(READY_FD, "")
    if fd.isdigit():
        with contextlib.suppress(OSError):  # the launcher is gone: nobody to tell
            os.write(int(fd), text.encode()[:512] + b"\n")
            os.close(int(fd))


def _interrupted(alive: Callable[[], str | None], stop: threading.Event) -> str | None:
    """Why waiting for the API must end (a child died, or a stop was asked), or None."""
    dead = alive()
    if dead is not None:
        return dead
    return "stopped before the API was ready" if stop.is_set() else None


def wait_signal(fd: int, alive: Callable[[], str | None], stop: threading.Event, timeout_s: float) -> str | None:
    """Wait for :func:`notify_ready`'s line on ``fd``: None once it said ready, else why not (a
    child that died, a stop request, the time limit, or the API's own reason)."""
    deadline = time.monotonic() + timeout_s
    received = b""
    while True:
        problem = _interrupted(alive, stop)
        if problem is not None:
            return problem
        if time.monotonic() > deadline:
            return f"the API was not ready within {timeout_s:g} s"
        readable, _, _ = select.select([fd], [], [], 0.1)
        if readable:
            chunk = os.read(fd, 512)
            received += chunk
            if not chunk and not received:  # the API exited: say how, once the exit is seen
                for _ in range(50):
                    dead = alive()
                    if dead is not None:
                        return dead
                    time.sleep(0.02)
            if not chunk or received.endswith(b"\n"):
                text = received.decode(errors="replace").strip()
                return None if text == "ready" else f"the API did not start: {text or 'it closed the pipe'}"


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
            problem = _interrupted(alive, stop)
            if problem is not None:
                return problem
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
                say(f"spacearm run: waiting for /readyz (it answers {last})", False)
                told = True
            stop.wait(interval)
            interval = min(1.0, 1.5 * interval)


def run(
    host: str,
    port: int,
    workers: int,
    ready_timeout_s: float,
    env: dict[str, str],
    say: Say,
    *,
    verbose: bool = False,
    api_processes: int = 1,
) -> int:
    """Migrate and compile (:func:`prepare_in_children`) while ``api_processes`` API processes
    on ``host:port`` and ``workers`` workers import their code (when compiling, from the end of
    its first part on), then let them start; say the URL
    once every API process is ready; return when stopped (0), when a child exits on its own (1),
    or with the exit code of a failed migration or compilation. Several API processes share the
    port (``SO_REUSEPORT``) and their metrics (:func:`shared_metrics_dir`)."""
    stop = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        stop.set()

    apis = ["API"] if api_processes == 1 else [f"API {i + 1}" for i in range(api_processes)]
    ready = {name: os.pipe() for name in apis}  # each API's readiness
    ours = [read for read, _ in ready.values()]  # our ends, closed at the end
    child_ends = [write for _, write in ready.values()]  # closed here once the children hold them
    gates: list[int] = []  # our ends of the children's gates
    children: dict[str, subprocess.Popen[bytes]] = {}
    metrics_dir = None
    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        # The API processes' environment: several share the port and a metrics folder; one has
        # neither (a PROMETHEUS_MULTIPROC_DIR of ours would add an earlier run's counts to its own).
        api_base = {k: v for k, v in env.items() if k != MULTIPROCESS_DIR} | {API_PROCESSES: str(api_processes)}
        if api_processes > 1:
            taken = port_taken(host, port)
            if taken is not None:
                say(f"spacearm run: {taken}", True)
                return 1
            metrics_dir, created = shared_metrics_dir(env)
            api_base[MULTIPROCESS_DIR] = metrics_dir
            metrics_dir = metrics_dir if created else None
        names = apis + [f"worker {i + 1}" if workers > 1 else "worker" for i in range(workers)]

        def start_children() -> None:
            if children:
                return
            for name in names:
                gate_read, gate_write = os.pipe()
                gates.append(gate_write)
                child_ends.append(gate_read)
                if name in ready:
                    ready_fd = ready[name][1]
                    api_env = {**api_base, GATE_FD: str(gate_read), READY_FD: str(ready_fd)}
                    api_args = ["serve", "--host", host, "--port", str(port)]
                    children[name] = start(api_args, api_env, (gate_read, ready_fd))
                else:
                    children[name] = start(["worker"], {**env, GATE_FD: str(gate_read)}, (gate_read,), nice=True)
            _close(child_ends)

        # The children import their code while the database is migrated. While the kernels are
        # compiled on a machine with no core to spare, only once the first part has ended: their
        # imports (some 5 s of CPU) then take the core it freed instead of CPU from the parts; a
        # first start to the URL took 2 s less on 2 cores (five pairs, alternated, 34-45 s).
        compiling = not kernels_compiled()
        if not compiling or spare_core_while_compiling():
            start_children()
        code = prepare_in_children(env, stop, verbose=verbose, compile=compiling, on_first_part=start_children)
        if code:
            return 0 if stop.is_set() else code
        start_children()
        for gate in gates:
            os.write(gate, b"go\n")

        def exited() -> str | None:
            for name, child in children.items():
                if child.poll() is not None:
                    return f"the {name} process exited with code {child.returncode}"
            return None

        url = local_url(host, port)
        # Each API says when its start-up (kernels, rehearsal) ended; then /readyz, which also
        # checks the database, confirms (polled only if it does not answer 200 at once).
        deadline = time.monotonic() + ready_timeout_s
        problem = None
        for read_fd, _ in ready.values():
            problem = problem or wait_signal(read_fd, exited, stop, max(1.0, deadline - time.monotonic()))
        if problem is None:
            problem = wait_ready(url, exited, stop, max(1.0, deadline - time.monotonic()), say)
        if problem is not None:
            if stop.is_set():
                return 0
            say(f"spacearm run: {problem} (see its log above); stopping", True)
            return 1
        where = f"{url} (docs at {url}/docs, metrics at {url}/metrics)"
        processes = f" ({api_processes} processes)" if api_processes > 1 else ""
        say(f"spacearm API on {where}{processes}, {workers} worker(s); Ctrl-C stops them", False)
        while not stop.wait(0.5):
            problem = exited()
            if problem is not None:
                say(f"spacearm run: {problem}; stopping", True)
                return 1
        return 0
    finally:
        _close(child_ends)
        _close(gates)  # a gate closed unopened: its child exits
        _close(ours)
        _stop_all(children)
        if metrics_dir is not None:
            shutil.rmtree(metrics_dir, ignore_errors=True)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def port_taken(host: str, port: int) -> str | None:
    """Why ``host:port`` cannot be shared by our API processes (in use: by another program, or by
    another run's processes, which ``SO_REUSEPORT`` would let them share), or None."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            return f"cannot bind {host}:{port}: {exc.strerror or exc}"
    return None


def shared_metrics_dir(env: dict[str, str]) -> tuple[str, bool]:
    """The directory several API processes share their metrics in (prometheus-client's
    multiprocess mode, :mod:`service.infra.metrics`): ``PROMETHEUS_MULTIPROC_DIR`` if set (its
    files of an earlier run removed: their counts would be added to this run's), else a new
    temporary one (removed when the run ends). Returns it and whether it was created."""
    given = env.get(MULTIPROCESS_DIR, "")
    if not given:
        return tempfile.mkdtemp(prefix="spacearm-metrics-"), True
    folder = Path(given)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.glob("*.db"):
        stale.unlink(missing_ok=True)
    return str(folder), False


def _close(fds: list[int]) -> None:
    """Close each of ``fds`` and empty the list (so that a second call closes nothing)."""
    while fds:
        with contextlib.suppress(OSError):
            os.close(fds.pop())


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
