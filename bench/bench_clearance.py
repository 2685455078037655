"""The cost of clearance (issue 19) on the raster-target preset's scene: µs per plan-step of the
same raster on the Table-1 robot without geometry, and on ``table1-geometry`` (six capsule
links, a carrier cube) among the target's two boxes (22 pairs: links and carrier against the
obstacles, the carrier against links 2-6, links two or more apart), measured in one run.

- ``plan_batch`` (GA evaluation: metrics only, one thread), adaptive damping (no avoidance) and
  the bounded inverse (velocity dampers in its QP);
- ``plan`` (one plan, every sample kept: every pair's distance at every sample, for the trace).

The goal: clearance under 30 % on top of the plan for GA evaluation. Medians of several rounds.

Run: ``.venv/bin/python bench/bench_clearance.py``
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's engine

from engine import CartesianTask, make_inverse, plan, plan_batch, table1_robot
from engine.model import table1_with_geometry
from service.usecases.presets import PRESETS

ROUNDS = 7
BATCH = 64


def _median_us(fn: Callable[[], object], per: int) -> float:
    fn()
    times = []
    for _ in range(ROUNDS):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e6 * statistics.median(times) / per


def main() -> None:
    preset = PRESETS["raster-target"]
    plain_model, geo_model = table1_robot(), table1_with_geometry()
    with_scene = preset.task.to_engine(geo_model)
    without = CartesianTask(
        q0=with_scene.q0, path=with_scene.path, dt=with_scene.dt, joint_speed_limit=with_scene.joint_speed_limit
    )
    steps = with_scene.n_steps
    rows = []
    for method, params in (("adaptive", {"lambda_max": 0.02038, "epsilon": 0.12}), ("bounded", {"lambda": 0.02})):
        columns = {k: np.full(BATCH, v) for k, v in params.items()}
        base = _median_us(lambda m=method, c=columns: plan_batch(plain_model, without, m, c, threads=1), BATCH * steps)
        geo = _median_us(lambda m=method, c=columns: plan_batch(geo_model, with_scene, m, c, threads=1), BATCH * steps)
        rows.append((f"plan_batch B={BATCH}, 1 thread, {method}", base, geo))
        inverse = make_inverse(method, **params)
        base = _median_us(lambda i=inverse: plan(plain_model, without, i), steps)
        geo = _median_us(lambda i=inverse: plan(geo_model, with_scene, i), steps)
        rows.append((f"plan (every sample kept), {method}", base, geo))
    print(f"raster-target: {steps} plan-steps, {len(with_scene.scene.obstacles)} obstacles")
    print(f"{'variant':44s} {'no geometry':>12s} {'geometry':>10s} {'clearance':>10s}")
    for name, base, geo in rows:
        print(f"{name:44s} {base:10.2f} us {geo:8.2f} us {100 * (geo / base - 1):+9.0f} %")


if __name__ == "__main__":
    main()
