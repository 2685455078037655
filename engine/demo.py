"""`python -m engine.demo`: the paper's task planned with every inverse, as a table."""

from __future__ import annotations

import math

from engine import make_inverse, method_names, paper_task, plan, replay, table1_robot


def comparison_table() -> str:
    model = table1_robot()
    task = paper_task(model)
    lines = [
        f"Paper task: {task.n_steps} steps of {task.dt} s, joint speed limit {math.degrees(task.joint_speed_limit):.0f} deg/s",
        f"{'method':9s} {'B (max)':>9s} {'pos max mm':>10s} {'att max deg':>11s} {'qd max deg/s':>12s} "
        f"{'min sigma':>9s} {'t(min|det|) s':>13s} {'replay gap mm':>13s}  verdict",
    ]
    for name in method_names():
        result = plan(model, task, make_inverse(name))
        m = result.metrics
        gap = replay(model, result).plan_gap_position_max * 1e3 if m.finite else float("nan")
        lines.append(
            f"{name:9s} {m.objective_b:9.5f} {m.position_error_max * 1e3:10.3f} {math.degrees(m.attitude_error_max):11.3f} "
            f"{m.max_joint_speed_deg_s:12.2f} {m.min_singular_value:9.2e} {m.time_of_min_abs_det_J_g:13.2f} {gap:13.1e}  "
            f"{'ok' if result.success else result.message}"
        )
    lines.append("Parameters are each method's defaults; GA tuning (engine.tuning) searches them.")
    return "\n".join(lines)


def main() -> None:
    print(comparison_table())


if __name__ == "__main__":
    main()
