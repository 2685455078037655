"""Load (or compile) every compiled kernel before the first real request.

numba compiles a kernel on its first call and keeps the machine code in its on-disk cache
(``NUMBA_CACHE_DIR``, or ``__pycache__`` beside the kernels); a process that starts with a warm
cache loads the kernels in under a second, a cold one compiles them (30 s to a minute). The API
and the workers call :func:`warm_up` at start-up so that no user request pays for it.

The kernels fall into :data:`PARTS`, so a cold cache is filled by one process per part at once
(:func:`compile_kernels`, what ``spacearm compile`` and ``spacearm run`` use): the planner's
step loop alone is most of the work, and the other part runs beside it on the second core,
starting with the loop's largest callees (:func:`_compile_loop_callees`) so that the loop's compilation
loads them instead of compiling them. A marker file (:mod:`engine.kernels.cache`) records that
every part was compiled for this CPU, so a later start knows without importing anything heavy.
"""

from __future__ import annotations

import contextlib
import gc
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
from numba import typeof, types

from engine.executed import executed_motion, executed_trajectory
from engine.geometry import capsule, distance, shape_from_dict
from engine.inverses import make_inverse, method_names
from engine.jacobian import generalized_jacobian
from engine.kernels import dynamics as dynamics_kernels
from engine.kernels import geometry as geometry_kernels
from engine.kernels import qp as qp_kernels
from engine.kernels import replay as replay_kernels
from engine.kernels import svd as svd_kernels
from engine.kernels.cache import HERE as KERNELS_DIR
from engine.kernels.cache import cpu_tag, marker_path
from engine.kernels.jit import CACHE_DIR, KERNELS, park_linking_modules
from engine.kinematics import State, forward_kinematics, kinematics_batch
from engine.model import RobotModel, table1_robot
from engine.planner import plan, plan_batch
from engine.replay import replay
from engine.spatial import exp_so3, log_so3, matrix_to_quaternion, quaternion_to_matrix, rotation_angle
from engine.trajectory import CartesianTask

Q0 = np.radians([175.0, -60.0, -60.0, 0.0, 210.0, 5.0])


def _task(robot: RobotModel) -> CartesianTask:
    """A two-step task of the Table-1 robot (every code path of a plan, in microseconds)."""
    fk = forward_kinematics(robot, State(Q0))
    return CartesianTask.from_q0(
        robot,
        Q0,
        fk.ee_position + 0.001,
        fk.ee_attitude,
        duration=0.5,
        ramp_time=0.1,
        dt=0.25,
        joint_speed_limit=math.radians(6.0),
    )


def _planner(robot: RobotModel) -> None:
    """The step loop: a plan of every inverse method with its trace, and a batch of metrics."""
    task = _task(robot)
    for name in method_names():
        plan(robot, task, make_inverse(name), feedback_gain=0.5)
    plan_batch(robot, task, "adaptive", {"lambda_max": [0.05, 0.06], "epsilon": [0.06, 0.07]}, threads=2)


def loop_callees(robot: RobotModel) -> list[tuple[Any, tuple[Any, ...]]]:
    """The step loop's largest callees, each with the argument types (numba's) the loop gives it:
    the clearance check's distance (GJK and EPA), the bounded inverse's QP, the executed
    trajectory's dynamics and the SVD, about 20 s of the planner part's compilation
    (:func:`_compile_loop_callees`). The buffers that give the types are made by the kernels'
    Python functions: compiling them first would delay the callees by a second and a half. The
    planner part's compilation gets to them in the order distance, SVD, QP, dynamics (10, 13,
    16 and 17 s after the start, 2026-11-29), sooner than the tools part can have compiled all
    four (18 s): the SVD, the quickest (2 s), comes last, so that the planner part compiles that
    one itself and loads the other three (with it second, the dynamics came 1 s late and the
    planner part compiled them, 4 s: a cold compilation of 34 s instead of 31). The loop calls
    them by symbol (:func:`engine.kernels.jit.unlinked`): their code is not generated again in
    the loop's."""
    n = robot.n_joints
    array1, array2 = typeof(np.zeros(1)), typeof(np.zeros((1, 1)))
    return [
        (geometry_kernels.shape_distance, (array1, array1, array2, typeof(geometry_kernels.gjk_buffers.py_func()), array2)),
        (
            qp_kernels.dls_qp,
            # the loop passes max_iter 0 in unlinked's argument tuple, where numba types it int64
            (array2, array1, array2, array1, types.float64, array1, array1, array1, array2, array1, types.int64)
            + (typeof(qp_kernels.qp_buffers.py_func(n, 0)),),
        ),
        (
            dynamics_kernels.trajectory_dynamics,
            (typeof(robot.chain), types.float64, types.int64, array1)
            + (typeof(dynamics_kernels.trajectory_buffers.py_func(3, n, 1)), types.boolean),
        ),
        (svd_kernels.jacobi_svd, (array2, typeof(svd_kernels.svd_buffers.py_func(n, 6)), types.boolean)),
    ]


def _compile_loop_callees(robot: RobotModel) -> None:
    """Compile (without running) :func:`loop_callees`. The tools part does this first, so that
    the planner part finds them in the cache when it gets to them and loads them (if it gets
    there first, it compiles them itself: the same code, in the same time as without this)."""
    for kernel, argument_types in loop_callees(robot):
        kernel.compile(argument_types)


def kernel_name(kernel: Any) -> str:
    """A kernel's name in the records: ``module.qualname`` (two modules may use one name)."""
    return f"{kernel.py_func.__module__}.{kernel.py_func.__qualname__}"


def signatures_path(part: str) -> Path:
    """The file in the kernel cache with the signatures of every kernel the compile part ``part``
    compiled or loaded on this CPU, written where the part was compiled."""
    return CACHE_DIR / f"signatures-{part}-{cpu_tag()}"


def _record_signatures(part: str) -> None:
    """Write :func:`signatures_path`: ``{"module.kernel": [signature, ...]}`` of this process,
    which has just compiled ``part``. A kernel compiled here lists what its callers asked for,
    nested calls included; one loaded from the cache hides its callees, which the part that
    compiled it lists. So in a fresh cache the parts' records together hold every signature
    (a literal argument, ``True`` or ``0``, is a signature of its own and a compilation more)."""
    held = {kernel_name(k): sorted(map(str, k.signatures)) for k in KERNELS}
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    signatures_path(part).write_text(json.dumps({k: v for k, v in held.items() if v}, indent=1, sort_keys=True) + "\n")


def _tools(robot: RobotModel) -> None:
    """Everything but the step loop: the replay's integrators (on a still motion of three
    samples, the argument types of :func:`engine.replay.replay`) and the executed trajectory's
    spline and integration, the figures' kinematics and distances, every inverse on one GJM, and
    the SO(3) helpers; first, the step loop's largest callees (:func:`_compile_loop_callees`)."""
    _compile_loop_callees(robot)
    t = np.array([0.0, 0.25, 0.5])
    q = np.repeat(Q0[None], 3, axis=0)
    qd = np.zeros_like(q)
    ys = np.zeros((3, 7))
    ys[0, 3] = 1.0
    replay_kernels.integrate(robot.chain, t, q, qd, ys, 1e-9, 1e-12)
    samples = (np.empty((3, 3)), np.empty((3, 3, 3)), np.empty((3, 3, 3)), np.empty(3), np.empty(3), np.empty((3, 3)))
    replay_kernels.evaluate_samples(robot.chain, q, qd, ys, *samples)
    executed_motion(robot, executed_trajectory(t, q), np.zeros(3), np.eye(3))  # a plan response's executed trajectory
    kinematics_batch(robot, q, np.repeat(np.eye(3)[None], 3, axis=0), np.zeros((3, 3)))  # the figures' arm
    distance(shape_from_dict({"type": "sphere", "radius_m": 0.1}), capsule([1, 0, 0], [1, 0, 1], 0.1))  # the clearance figure
    J_g = generalized_jacobian(robot, State(Q0)).J_g
    for name in method_names():
        make_inverse(name).solve(J_g, np.ones(6))
    R = exp_so3(np.array([0.1, 0.2, 0.3]))
    log_so3(R)
    rotation_angle(R)
    quaternion_to_matrix(matrix_to_quaternion(R))


#: The kernels by part, in the order a single process warms them.
PARTS: dict[str, Callable[[RobotModel], None]] = {"planner": _planner, "tools": _tools}


def warm_up(parts: Sequence[str] = tuple(PARTS), *, record: bool = False) -> float:
    """Run every kernel of ``parts`` (default: all) once on a two-step task of the Table-1 robot
    (every inverse method, plans with and without traces, the replay, the GJM and the SO(3)
    helpers), then park the loaded kernels' linking modules
    (:func:`engine.kernels.jit.park_linking_modules`). Returns the seconds it took.

    ``record``: if this process compiles ``parts`` (one part: :func:`compile_kernels`' children),
    write :func:`_record_signatures` (another process may have called kernels from Python first,
    with other types)."""
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise ValueError(f"unknown kernel part(s) {sorted(unknown)}; the parts are {list(PARTS)}")
    if record and len(parts) != 1:
        raise ValueError("record: one part per process (the records are per part)")
    start = time.perf_counter()
    robot = table1_robot()
    for name in parts:
        PARTS[name](robot)
        if record and any(k.stats.cache_misses for k in KERNELS):
            _record_signatures(name)
    if set(parts) == set(PARTS):
        # the replay as the API runs it, from a real plan (its arguments' types as callers pass them)
        replay(robot, plan(robot, _task(robot), make_inverse("adaptive")))
    park_linking_modules()
    return time.perf_counter() - start


@dataclass(frozen=True)
class Progress:
    """What :func:`compile_kernels` reports: ``done`` parts of ``total``, the parts still running
    and the seconds since it started."""

    done: int
    total: int
    running: tuple[str, ...]
    seconds: float


class CompileError(RuntimeError):
    """A part failed to compile (the message has the child's last lines)."""


def compile_kernels(on_progress: Callable[[Progress], None], *, every_s: float = 10.0) -> float:
    """Compile every part into the kernel cache, one child process per part at once, and write
    the marker of :func:`engine.kernels.cache.marker_path` (:func:`engine.kernels.cache.compiled`
    then says so). ``on_progress`` is called when a part ends and every ``every_s`` seconds
    meanwhile. Returns the seconds it took."""
    start = time.monotonic()
    with contextlib.ExitStack() as files:
        # the children's output goes to files, not pipes: a child never blocks on a full pipe
        logs = {name: files.enter_context(tempfile.TemporaryFile("w+")) for name in PARTS}
        running = {name: subprocess.Popen(_command(name), stdout=logs[name], stderr=subprocess.STDOUT) for name in PARTS}
        try:
            _watch(running, logs, start, on_progress, every_s)
        finally:
            for child in running.values():
                child.kill()
                child.wait()
    seconds = time.monotonic() - start
    CACHE_DIR.mkdir(parents=True, exist_ok=True)
    marker_path(CACHE_DIR).write_text(f"compiled in {seconds:.1f} s\n")
    remove_stale_caches()
    return seconds


def remove_stale_caches() -> list[Path]:
    """Delete the in-tree caches of earlier kernel sources (``engine/kernels/__pycache__/
    numba-<hash>`` beside :data:`CACHE_DIR`): this tree can no longer run the code they hold, and
    each is some 14 MiB. Caches elsewhere (``NUMBA_CACHE_DIR``, ``~/.cache``) may serve other
    installs and are left alone. Returns the folders deleted."""
    if CACHE_DIR.parent != KERNELS_DIR / "__pycache__":
        return []
    stale = [p for p in CACHE_DIR.parent.glob("numba-*") if p.is_dir() and p != CACHE_DIR]
    for folder in stale:
        shutil.rmtree(folder, ignore_errors=True)
    return stale


#: The cyclic garbage collector's thresholds while a child compiles (Python's default: 700, 10,
#: 10). numba's compilation allocates millions of objects, most freed by reference counting; with
#: the default a collection ran every 700 allocations, 6.7 s of the planner part's 60 s alone
#: (gen0 3,967 times, full 28 times). With these, 1.4 s (gen0 27 times), for a peak RSS of 613 MiB
#: instead of 524: the garbage in cycles that reaches the older generations stays until the child
#: exits, seconds later.
COMPILE_GC_THRESHOLDS = (100_000, 50, 100)


def compile_part(part: str) -> None:
    """What a child of :func:`compile_kernels` runs: :func:`warm_up` of ``part``, recording its
    signatures, with the collector's :data:`COMPILE_GC_THRESHOLDS` (put back after)."""
    thresholds = gc.get_threshold()
    gc.set_threshold(*COMPILE_GC_THRESHOLDS)
    try:
        warm_up([part], record=True)
    finally:
        gc.set_threshold(*thresholds)


def _command(part: str) -> list[str]:
    """A child compiling ``part`` (:func:`compile_part`) with this very engine package (numba keys
    its cache by the kernels' source paths: a source tree in the working directory must not stand
    in for it)."""
    root = str(Path(__file__).resolve().parent.parent)
    code = "import sys; sys.path.insert(0, sys.argv[1]); from engine.warmup import compile_part; compile_part(sys.argv[2])"
    return [sys.executable, "-P", "-c", code, root, part]


def _watch(
    running: dict[str, subprocess.Popen[bytes]],
    logs: Mapping[str, IO[str]],
    start: float,
    on_progress: Callable[[Progress], None],
    every_s: float,
) -> None:
    """Wait for the ``running`` children (removing each as it ends), reporting progress."""

    def report(now: float) -> float:
        on_progress(Progress(len(PARTS) - len(running), len(PARTS), tuple(running), now - start))
        return now

    last = start
    while running:
        time.sleep(0.1)
        for name, child in list(running.items()):
            if child.poll() is None:
                continue
            del running[name]
            if child.returncode != 0:
                logs[name].seek(0)
                tail = "\n".join(logs[name].read().strip().splitlines()[-5:])
                raise CompileError(f"compiling the {name} kernels failed (exit code {child.returncode}): {tail}")
            last = report(time.monotonic())
        if running and time.monotonic() - last >= every_s:
            last = report(time.monotonic())
