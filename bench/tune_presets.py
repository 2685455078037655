"""Tune the adaptive damping of the inspection presets (``GET /v1/task-presets``) with the
paper's GA and compare with the parameters stored in ``service/usecases/presets.py``.

Each preset with a stated method is tuned on its task (population 16, 10 generations, seed 1,
B with weights (0.5, 0.5), max aggregation, angle attitude term: the settings the stored
parameters came from); the stored and the tuned parameters are then planned and replayed.

Run: `.venv/bin/python bench/tune_presets.py [name ...]`.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from engine import make_inverse, plan, replay, table1_robot, tune, warm_up
from service.usecases.presets import PRESETS

POPULATION, GENERATIONS, SEED = 16, 10, 1


def main(names: list[str]) -> None:
    warm_up()
    model = table1_robot()
    for name in names or [n for n, p in PRESETS.items() if p.method is not None]:
        preset = PRESETS[name]
        task = preset.task.to_engine(model)
        start = time.perf_counter()
        tuned = tune(model, task, "adaptive", population=POPULATION, generations=GENERATIONS, seed=SEED)
        elapsed = time.perf_counter() - start
        print(f"{name}: {task.kind}, {task.duration:.4g} s, {task.n_steps} steps; GA {elapsed:.1f} s, {tuned.evaluations} plans")
        print(f"  tuned  {tuned.best_params}  B = {tuned.best_objective_b:.6g}  ({tuned.message})")
        stored = preset.method.params.given() if preset.method else {}
        for label, params in (("stored", stored), ("tuned", tuned.best_params)):
            result = plan(model, task, make_inverse("adaptive", **params))
            check = replay(model, result)
            print(
                f"  {label:6s} success={result.success} B={result.metrics.objective_b:.6g} "
                f"max speed {result.metrics.max_joint_speed_deg_s:.4g} deg/s, "
                f"max error {result.metrics.position_error_max * 1e3:.3g} mm; replay gap "
                f"{check.plan_gap_position_max * 1e3:.3g} mm ({check.message}); {result.message}"
            )


if __name__ == "__main__":
    main(sys.argv[1:])
