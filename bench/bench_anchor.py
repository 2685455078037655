"""The compiled anchor (issue 21): the paper's planner loop in C++ with Pinocchio and Eigen
(``bench/anchor/plan_loop.cpp``: Pinocchio's frame Jacobian and centroidal map for the GJM,
Eigen's JacobiSVD and eq. 16, the engine's fourth-order Magnus carrier step; no engine code),
built here from the ``pin`` wheel's headers and libraries and the ``cmeel-eigen`` wheel's Eigen
(installed into this environment if missing), checked against ``engine.plan`` on the paper task,
and every engine row reported as a ratio to it, measured in one run.

Run: ``.venv/bin/python bench/bench_anchor.py`` (the first run compiles for about a minute).
"""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
import sysconfig
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's engine

from engine import make_inverse, paper_task, plan_batch, run_plan, table1_robot  # noqa: E402
from engine.planner import PlanSetup  # noqa: E402
from engine.trajectory import PAPER_TASK_PARAMS  # noqa: E402

sys.path.insert(0, str(ROOT / "bench"))
from bench_engine import median_time  # noqa: E402

SOURCE = ROOT / "bench" / "anchor" / "plan_loop.cpp"
BUILD = ROOT / "bench" / "anchor" / "build"
REPEATS = 200
ROUNDS = 7


def prefix() -> Path:
    """The cmeel prefix of the ``pin`` wheel (headers and libraries), with Eigen's headers."""
    path = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix"
    if not (path / "include" / "eigen3" / "Eigen" / "Dense").exists():
        print("installing Eigen's headers (the cmeel-eigen wheel) ...", flush=True)
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "cmeel-eigen"], check=True)
    if importlib.util.find_spec("pinocchio") is None:
        sys.exit("pinocchio (the pin wheel, a test dependency) is not installed: make test installs it")
    return path


def build() -> Path:
    binary = BUILD / "plan_loop"
    if binary.exists() and binary.stat().st_mtime > SOURCE.stat().st_mtime:
        return binary
    BUILD.mkdir(exist_ok=True)
    p = prefix()
    command = [
        "g++", "-O3", "-march=native", "-DNDEBUG", "-std=c++17", str(SOURCE), "-o", str(binary),
        # what pinocchio's CMake package gives its users (lib/cmake/pinocchio): boost::variant of its 25 joints
        "-DBOOST_MPL_LIMIT_LIST_SIZE=30", "-DBOOST_MPL_LIMIT_VECTOR_SIZE=30", "-DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS",
        "-DBOOST_FUSION_INVOKE_MAX_ARITY=12",
        f"-I{p / 'include'}", f"-I{p / 'include' / 'eigen3'}", f"-L{p / 'lib'}", f"-Wl,-rpath,{p / 'lib'}",
        "-lpinocchio_default", "-lboost_filesystem", "-lboost_serialization",
    ]  # fmt: skip
    print("compiling the anchor:", " ".join(command[:6]), "...", flush=True)
    subprocess.run(command, check=True)
    return binary


def anchor_input(repeats: int) -> str:
    model = table1_robot()
    task = paper_task(model)
    samples = task.samples
    params = PAPER_TASK_PARAMS["adaptive"]
    numbers: list[float] = [model.n_joints, model.base.mass, *model.base.inertia.ravel(), *model.base.b]
    for link in model.links:
        numbers += [link.mass, *link.inertia.ravel(), *link.joint_axis, *link.a, *link.b]
    numbers += [*np.asarray(model.C_e).ravel(), *task.q0, task.n_steps, task.dt, params["lambda_max"], params["epsilon"], repeats]
    numbers += [*samples.twists.ravel(), *samples.p_des.ravel()]
    return " ".join(repr(float(x)) if not float(x).is_integer() or abs(x) > 1e6 else str(int(x)) for x in numbers)


def run_anchor(binary: Path, repeats: int) -> dict[str, object]:
    out = subprocess.run([str(binary)], input=anchor_input(repeats), capture_output=True, text=True, check=True).stdout
    lines = dict(line.split(" ", 1) for line in out.strip().splitlines())
    return {
        "q": np.array([float(x) for x in lines["q"].split()]),
        "pos_max": float(lines["pos_max"]),
        "seconds_per_step": float(lines["seconds_per_step"]),
    }


def median_s(fn: Callable[[], object], rounds: int = ROUNDS) -> float:
    fn()  # compiled and warm
    return median_time(fn, rounds)


def measure() -> dict[str, object]:
    """The anchor and the engine's rows on the paper task (µs per plan-step), the anchor's
    agreement with ``engine.plan`` (``gap``, rad) and the issue's kernel goals as
    ``(text, value, met)``."""
    binary = build()
    model = table1_robot()
    task = paper_task(model)
    params = PAPER_TASK_PARAMS["adaptive"]
    inverse = make_inverse("adaptive", **params)
    setup = PlanSetup(model, task)
    planned = run_plan(setup, inverse)
    anchor = run_anchor(binary, 1)
    gap = float(np.max(np.abs(np.asarray(anchor["q"]) - planned.q[-1])))
    print(f"anchor against engine.plan: final joints within {gap:.1e} rad; largest position error "
          f"{float(anchor['pos_max']) * 1e3:.4f} mm against {planned.metrics.position_error_max * 1e3:.4f} mm")  # fmt: skip
    if not math.isfinite(gap) or gap > 1e-9:
        sys.exit(f"the anchor does not reproduce engine.plan (gap {gap:.2e} rad): its timings are not comparable")
    steps = task.n_steps + 1
    anchor_us = float(run_anchor(binary, REPEATS)["seconds_per_step"]) * 1e6
    rows = [("C++ Pinocchio + Eigen loop (the anchor)", anchor_us)]
    rows.append(("engine.plan (one plan, every sample kept)", median_s(lambda: run_plan(setup, inverse)) / steps * 1e6))
    batch = {k: np.full(64, v) for k, v in params.items()}
    for threads in (1, 2):
        seconds = median_s(lambda threads=threads: plan_batch(model, task, "adaptive", batch, threads=threads))
        rows.append((f"engine.plan_batch, B=64, {threads} thread(s)", seconds / (64 * steps) * 1e6))
    scaling = rows[2][1] / rows[3][1]
    goals = [
        ("batch evaluation per core <= 1.5 µs per plan-step", f"{rows[2][1]:.2f} µs", rows[2][1] <= 1.5),
        ("a single plan <= 3 µs per plan-step", f"{rows[1][1]:.2f} µs", rows[1][1] <= 3.0),
        ("2 threads >= 1.7x one (plan_batch B=64)", f"{scaling:.2f}x", scaling >= 1.7),
    ]
    return {"anchor_us": anchor_us, "rows": rows, "gap": gap, "goals": goals}


def main() -> None:
    measured = measure()
    anchor_us = float(measured["anchor_us"])  # type: ignore[arg-type]
    print(f"\n{'paper task, adaptive damping':<46}{'µs per plan-step':>18}{'anchor / row':>14}")
    for name, us in measured["rows"]:  # type: ignore[attr-defined]
        print(f"{name:<46}{us:>18.2f}{anchor_us / us:>13.2f}x")
    for text, value, met in measured["goals"]:  # type: ignore[attr-defined]
        print(f"goal: {text}: {value}, {'met' if met else 'missed'}")


if __name__ == "__main__":
    main()
