"""`python -m engine.demo`: the paper's task planned with every inverse, as a table.

Each method runs with parameters that succeed on the paper's task where the engine has them
(:data:`engine.trajectory.PAPER_TASK_PARAMS`: the GA optima of the README's tuning job), else
its defaults; then the paper's own GA optimum, which breaks the 6 deg/s limit on this robot.
"""

from __future__ import annotations

import math

from engine import make_inverse, method_names, paper_task, plan, replay, table1_robot
from engine.inverses import Inverse
from engine.trajectory import PAPER_GA_OPTIMUM, PAPER_TASK_PARAMS


def comparison_table() -> str:
    model = table1_robot()
    task = paper_task(model)
    lines = [
        f"Paper task: {task.n_steps} steps of {task.dt} s, joint speed limit {math.degrees(task.joint_speed_limit):.0f} deg/s, "
        f"torque limits {', '.join(f'{x:g}' for x in model.effort_limits)} N m",
        f"{'method':9s} {'B (max)':>9s} {'pos max mm':>10s} {'att max deg':>11s} {'qd max deg/s':>12s} {'tau max N m':>11s} "
        f"{'min sigma':>9s} {'t(min|det|) s':>13s} {'replay gap mm':>13s}  parameters: verdict",
    ]

    def row(name: str, inverse: Inverse) -> str:
        result = plan(model, task, inverse)
        m = result.metrics
        gap = replay(model, result).plan_gap_position_max * 1e3 if m.finite else float("nan")
        params = ", ".join(f"{k} {v:g}" for k, v in inverse.scalar_params().items()) or "none"
        return (
            f"{name:9s} {m.objective_b:9.5f} {m.position_error_max * 1e3:10.3f} {math.degrees(m.attitude_error_max):11.3f} "
            f"{m.max_joint_speed_deg_s:12.2f} {m.max_joint_torque:11.3f} {m.min_singular_value:9.2e} "
            f"{m.time_of_min_abs_det_J_g:13.2f} {gap:13.1e}  {params}: {'ok' if result.success else result.message}"
        )

    for name in method_names():
        lines.append(row(name, make_inverse(name, **PAPER_TASK_PARAMS.get(name, {}))))
    lines.append(row("paper GA", make_inverse("adaptive", **PAPER_GA_OPTIMUM)))
    lines.append(
        "Parameters: the GA optima of this robot where the engine has them (engine.trajectory.PAPER_TASK_PARAMS), else "
        "each method's defaults; 'paper GA' is the paper's own optimum for its exact robot, over 6 deg/s on this "
        "reconstruction. GA tuning (engine.tuning) searches them."
    )
    return "\n".join(lines)


def main() -> None:
    print(comparison_table())


if __name__ == "__main__":
    main()
