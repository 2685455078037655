"""Figure benchmark: every plan figure of a 20,000-step plan (the paper's line stretched to
500 s with dt 0.025 s), rendered from the stored JSON exactly as the service does, in SVG and
PNG; prints the time per figure (and the one-off JSON decoding). Not a timed test.

Run: `.venv/bin/python bench/bench_figures.py` (the `make bench` target runs the engine
benchmarks; this one is separate).
"""

from __future__ import annotations

import math
import time

import numpy as np

from engine import CartesianTask, make_inverse, paper_task, plan, table1_robot
from service import figures
from service.infra.storage import pack_trajectory, unpack_trajectory
from service.schemas.methods import MethodOut
from service.schemas.plans import metrics_out
from service.usecases.plans import record_from_storage, record_of

DURATION_S, DT_S = 500.0, 0.025


def main() -> None:
    robot = table1_robot()
    paper = paper_task(robot)
    task = CartesianTask.from_q0(
        robot,
        paper.q0,
        paper.target_position,
        paper.target_attitude,
        duration=DURATION_S,
        ramp_time=50.0,
        dt=DT_S,
        profile="trapezoidal",
        joint_speed_limit=math.radians(6.0),
    )
    start = time.perf_counter()
    result = plan(robot, task, make_inverse("adaptive", lambda_max=0.0571, epsilon=0.0677))
    print(f"plan: {len(result.t) - 1} steps in {time.perf_counter() - start:.2f} s ({result.message})")
    stored = pack_trajectory(record_of(result, robot))
    start = time.perf_counter()
    data = figures.PlanData(
        record_from_storage(unpack_trajectory(stored)),
        plan_id="bench",
        method=MethodOut.from_engine(result.inverse, None).model_dump(mode="json"),
        metrics=metrics_out(result.metrics),
        robot=robot.to_dict(),  # the arm of the 3D view
    )
    print(f"stored record: {len(stored) / 1e6:.1f} MB, decoded to arrays in {time.perf_counter() - start:.3f} s")
    print(f"{'figure':<18} {'svg [s]':>8} {'svg [kB]':>9} {'png [s]':>8} {'png [kB]':>9}")
    totals = {"svg": 0.0, "png": 0.0}
    for name in figures.PLAN_FIGURES:
        row = [f"{name:<18}"]
        for fmt in ("svg", "png"):
            start = time.perf_counter()
            content = figures.render_plan_figure(data, name, fmt)
            elapsed = time.perf_counter() - start
            totals[fmt] += elapsed
            row.append(f"{elapsed:8.3f} {len(content) / 1e3:9.1f}")
        print(" ".join(row))
    print(f"{'all figures':<18} {totals['svg']:8.3f} {'':>9} {totals['png']:8.3f}")
    start = time.perf_counter()
    figures.render_compare_figure([data, data], "svg")
    print(f"compare tracking-errors (2 plans, svg): {time.perf_counter() - start:.3f} s")
    start = time.perf_counter()
    figures.render_compare_figure([data, data], "svg", name="joint-velocities")
    print(f"compare joint-velocities (2 plans, svg): {time.perf_counter() - start:.3f} s")
    assert np.isfinite(data.t[-1])


if __name__ == "__main__":
    main()
