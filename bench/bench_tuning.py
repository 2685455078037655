"""GA tuning benchmark: paper-scale tuning (population 40, 50 generations, the paper's task)
in one run: wall time, plans per second, and the ratio against evaluating the same
individuals one by one with `plan`; then the fair DLS comparison.

Run: `.venv/bin/python bench/bench_tuning.py`.
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from engine import make_inverse, paper_task, plan, table1_robot
from engine.tuning import compare, tune

POPULATION, GENERATIONS, SEED = 40, 50, 1


def main() -> None:
    model = table1_robot()
    task = paper_task(model)
    tune(model, task, "adaptive", population=4, generations=1, seed=0)  # warm-up (imports, caches)

    start = time.perf_counter()
    result = tune(model, task, "adaptive", population=POPULATION, generations=GENERATIONS, seed=SEED)
    wall = time.perf_counter() - start
    rate = result.evaluations / wall

    # The same number of plans evaluated one by one with `plan` (a sample, extrapolated).
    rng = np.random.default_rng(0)
    sample = 60
    lam = rng.uniform(1e-4, 0.2, sample)
    eps = rng.uniform(1e-4, 0.3, sample)
    start = time.perf_counter()
    for a, b in zip(lam, eps, strict=True):
        plan(model, task, make_inverse("adaptive", lambda_max=a, epsilon=b))
    one_by_one = (time.perf_counter() - start) / sample

    print(f"tune(adaptive): population {POPULATION}, {GENERATIONS} generations, {result.evaluations} plans")
    print(f"  wall {wall:.3f} s (target < 1 s), {rate:.0f} plans/s, {wall / result.evaluations * 1e6:.0f} us per plan")
    print(
        f"  one by one with plan: {one_by_one * 1e3:.2f} ms per plan -> "
        f"{one_by_one * result.evaluations:.2f} s for the same plans"
    )
    print(f"  speed-up of the batched GA over one-by-one plans: {one_by_one * result.evaluations / wall:.1f}x")
    print(f"  best {result.best_params} B = {result.best_objective_b:.6f}")

    # The same run with the population split over both cores (a process pool as map_fn).
    with ProcessPoolExecutor(max_workers=2) as pool:
        tune(model, task, "adaptive", population=4, generations=1, seed=0, map_fn=pool.map, chunks=2)  # warm the pool
        start = time.perf_counter()
        pooled = tune(
            model, task, "adaptive", population=POPULATION, generations=GENERATIONS, seed=SEED, map_fn=pool.map, chunks=2
        )
        pooled_wall = time.perf_counter() - start
    assert pooled.best_params == result.best_params
    print(f"  with a 2-process pool (chunks=2): wall {pooled_wall:.3f} s, {wall / pooled_wall:.2f}x the single-process run")

    start = time.perf_counter()
    c = compare(model, task, population=POPULATION, generations=GENERATIONS, seed=SEED)
    wall = time.perf_counter() - start
    for r in (c.adaptive, c.dls):
        m = r.best_metrics[0]
        print(
            f"  {r.method:8s} {r.best_params} B = {r.best_objective_b:.6f} "
            f"(pos max {m.position_error_max * 1e3:.3f} mm, att max {np.degrees(m.attitude_error_max):.3f} deg, "
            f"qd max {m.max_joint_speed_deg_s:.3f} deg/s)"
        )
    print(f"compare(): improvement of adaptive over tuned DLS {c.improvement_percent:.1f}% (paper: 26.7%), {wall:.2f} s")


if __name__ == "__main__":
    main()
