"""Objective-landscape benchmark: a 64 x 64 grid of `lambda_max` x `epsilon` of the adaptive
damping on the paper task (4,096 plans of 61 samples, B, feasibility and peak joint speed per
cell), timed against an external anchor measured in the same run: the planner loop written with
Pinocchio's own functions (the anchor of `bench_engine.py`), one plan of the paper task, scaled
to the grid's 4,096 plans. The ratio says how many anchor plans the grid costs per cell.

Run: `.venv/bin/python bench/bench_landscape.py [--steps 64] [--rounds 3]` (needs the test extras: pin).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from pinocchio_oracle import build_pinocchio_model, pinocchio_plan

from engine import landscape, paper_task, table1_robot, warm_up
from engine.planner import default_threads

LAM_MAX, EPSILON = 0.0571, 0.0677


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=64, help="values per axis (default 64)")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds, median reported (default 3)")
    args = parser.parse_args()
    warm_up()
    model = table1_robot()
    task = paper_task(model)
    xs = np.linspace(1e-3, 0.2, args.steps)
    ys = np.linspace(1e-3, 1.0, args.steps)

    pm, fid = build_pinocchio_model(model)
    twists = task.samples.twists
    pinocchio_plan(pm, fid, task.q0, twists, task.dt, LAM_MAX, EPSILON)  # warm
    anchor = []
    for _ in range(args.rounds):
        start = time.perf_counter()
        pinocchio_plan(pm, fid, task.q0, twists, task.dt, LAM_MAX, EPSILON)
        anchor.append(time.perf_counter() - start)
    t_anchor_plan = statistics.median(anchor)

    results = {}
    for threads in sorted({1, default_threads()}):
        times = []
        for _ in range(args.rounds):
            start = time.perf_counter()
            grid = landscape(model, [task], "adaptive", ("lambda_max", xs), ("epsilon", ys), threads=threads)
            times.append(time.perf_counter() - start)
        results[threads] = (statistics.median(times), grid)

    cells = args.steps**2
    print(f"grid {args.steps} x {args.steps} = {cells} plans of {task.n_steps + 1} samples (paper task, adaptive)")
    print(f"anchor: one Pinocchio-loop plan {t_anchor_plan * 1e3:.2f} ms; x {cells} plans = {t_anchor_plan * cells:.2f} s")
    for threads, (t, grid) in results.items():
        print(
            f"engine.landscape, {threads} thread(s): {t:.3f} s  ({t / cells * 1e6:.1f} µs per cell; "
            f"{t_anchor_plan * cells / t:.1f}x faster than the anchor loop); "
            f"feasible {grid.feasible.mean():.1%}, best B {grid.best_objective_b:.5g} at {grid.best_params}"
        )


if __name__ == "__main__":
    main()
