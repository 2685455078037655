"""The paper's comparison with its third row: the adaptive damping (eq. 16), constant-damping DLS
and the ``bounded`` inverse, each tuned by the same binary GA (population 40, 50 generations, seed
1) on the paper's task and Table-1 robot, then planned with the tuned parameters: B, errors, peak
joint speed and torque per method (the README's table).

Run: `PYTHONPATH=. .venv/bin/python bench/compare_three.py`.
"""

from __future__ import annotations

import numpy as np

from engine import compare, make_inverse, paper_task, plan, table1_robot


def main() -> None:
    robot, task = table1_robot(), paper_task()
    c = compare(robot, task, population=40, generations=50, seed=1, refine=False)  # the paper's GA alone
    assert c.bounded is not None
    print(f"{'method':10s} {'parameters':44s} {'B':>8s} {'pos mm':>7s} {'att deg':>8s} {'deg/s':>6s} {'N m':>6s} success")
    for name, tuned in (("adaptive", c.adaptive), ("dls", c.dls), ("bounded", c.bounded)):
        result = plan(robot, task, make_inverse(name, **tuned.best_params))
        m = result.metrics
        params = ", ".join(f"{k} {v:.4g}" for k, v in tuned.best_params.items())
        print(
            f"{name:10s} {params:44s} {tuned.best_objective_b:8.5f} {m.position_error_max * 1e3:7.3f} "
            f"{np.degrees(m.attitude_error_max):8.3f} {m.max_joint_speed_deg_s:6.3f} {m.max_joint_torque:6.3f} {result.success}"
        )
    print(f"below DLS: adaptive {c.improvement_percent:.1f} %, bounded {c.bounded_improvement_percent:.1f} %")


if __name__ == "__main__":
    main()
