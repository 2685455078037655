"""The README's robustness figures (issue 20), measured: the paper plan (the README's GA
optimum, lambda_max 0.040, epsilon 0.37) on 64 robots sampled at ±10 % carrier mass and inertia,
open and closed loop; then robust tuning of the README job's GA (population 20, 20 generations,
seed 1, 16 samples, mean B) against nominal tuning and DLS tuned alike.

Run: ``.venv/bin/python bench/readme_robustness.py`` (about a minute).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's engine

from engine import PlanOptions, PlanSetup, Uncertainty, make_inverse, paper_task, robustness, run_plan, table1_robot
from engine.robustness import sampled_setups
from engine.trajectory import PAPER_TASK_PARAMS
from engine.tuning import TuningProblem, tune
from engine.uncertainty import draw


def mm(value: float) -> str:
    return f"{value * 1e3:.1f} mm"


def main() -> None:
    robot = table1_robot()
    task = paper_task(robot)
    setup = PlanSetup(robot, task, PlanOptions())
    inverse = make_inverse("adaptive", **PAPER_TASK_PARAMS["adaptive"])
    nominal = run_plan(setup, inverse)
    r = robustness(setup, inverse, nominal, Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, samples=64))
    print(f"paper plan {PAPER_TASK_PARAMS['adaptive']}: nominal largest position error {mm(nominal.metrics.position_error_max)}")
    for name, loop in (("open loop", r.open_loop), ("closed loop", r.closed_loop)):
        p = loop.position_error_max
        print(
            f"  {name}: mean {mm(p.mean)}, p95 {mm(p.p95)}, max {mm(p.max)}; attitude max "
            f"{math.degrees(loop.attitude_error_max.max):.2f} deg; limit broken on {loop.limit_broken_fraction:.0%}"
        )

    uncertainty = Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, samples=16)
    ga = {"population": 20, "generations": 20, "seed": 1}
    robust = tune(robot, task, "adaptive", uncertainty=uncertainty, **ga)
    dls = tune(robot, task, "dls", uncertainty=uncertainty, **ga)
    plain = tune(robot, task, "adaptive", **ga)
    problem = TuningProblem.build(robot, task, "adaptive", uncertainty=uncertainty)
    broken = sum(
        not math.isfinite(run_plan(s, make_inverse("adaptive", **plain.best_params)).metrics.objective_b)
        for s in sampled_setups(setup, draw(uncertainty, robot))
    )
    print("robust tuning, 16 samples, mean B (population 20 x 20 generations, seed 1):")
    for name, result in (("robust adaptive", robust), ("robust DLS", dls)):
        print(f"  {name} {result.best_params}: B {result.best_objective_b:.3g} (nominal robot {result.nominal_objective_b:.3g})")
    print(
        f"  nominal tuning {plain.best_params}: B {plain.best_objective_b:.3g} on the nominal robot, "
        f"{problem.objective_b(plain.best_params):.3g} over the samples (a limit broken on {broken} of 16)"
    )


if __name__ == "__main__":
    main()
