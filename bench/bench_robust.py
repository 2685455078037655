"""Robust tuning (issue 20) end to end against nominal tuning, measured in one run on the paper
task: the adaptive damping tuned by the GA (population 40, 50 generations, seed 1) and the
refinement, on the nominal robot and on 64 sampled robots (±10 % carrier mass and inertia,
closed loop, mean B). Each in a fresh process, which reports its plans, its time, its plans per
second and its peak memory (VmHWM) after the engine is loaded and after the tuning: the robust
job keeps population x samples numbers per generation, never traces.

Run: ``.venv/bin/python bench/bench_robust.py`` (about two minutes on two cores).
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent(
    """
    import json, sys, time
    sys.path.insert(0, {root!r})
    import engine
    from engine import paper_task, table1_robot
    from engine.tuning import tune
    from engine.uncertainty import Uncertainty

    def peak_mib():
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmHWM")) / 1024

    engine.warm_up()
    robot = table1_robot()
    task = paper_task(robot)
    samples = {samples}
    uncertainty = Uncertainty(carrier_mass_rel=0.1, carrier_inertia_rel=0.1, samples=samples) if samples else None
    before = peak_mib()
    start = time.perf_counter()
    result = tune(robot, task, "adaptive", population=40, generations=50, seed=1, uncertainty=uncertainty)
    elapsed = time.perf_counter() - start
    print(json.dumps({{
        "plans": result.evaluations, "elapsed_s": elapsed, "before_mib": before, "after_mib": peak_mib(),
        "best_objective_b": result.best_objective_b, "nominal_objective_b": result.nominal_objective_b,
        "best_params": result.best_params, "records": len(result.history),
    }}))
    """
)


def run(samples: int) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(root=str(ROOT), samples=samples)], capture_output=True, text=True, check=True
    )
    numbers: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return numbers


def main() -> None:
    nominal = run(0)
    robust = run(64)
    print("paper task, adaptive, population 40 x 50 generations + refinement, seed 1")
    print(f"{'job':<22}{'plans':>10}{'time s':>9}{'plans/s':>10}{'MiB before':>12}{'MiB after':>11}  B")
    for name, r in (("nominal", nominal), ("robust, 64 samples", robust)):
        rate = r["plans"] / r["elapsed_s"]
        print(
            f"{name:<22}{r['plans']:>10.0f}{r['elapsed_s']:>9.1f}{rate:>10.0f}{r['before_mib']:>12.0f}{r['after_mib']:>11.0f}"
            f"  {r['best_objective_b']:.6g} (nominal robot {r.get('nominal_objective_b')})"
        )
    ratio = (robust["plans"] / robust["elapsed_s"]) / (nominal["plans"] / nominal["elapsed_s"])
    print(f"robust plans/s over nominal plans/s: {ratio:.2f}")
    print(f"robust job's memory growth: {robust['after_mib'] - robust['before_mib']:.1f} MiB")


if __name__ == "__main__":
    main()
