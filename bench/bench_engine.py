"""Engine benchmark: time per plan-step of `plan`, `plan_batch` (batches 1, 16, 64, 256) and a
Pinocchio-based reference loop doing the same GJM + adaptive inverse, as ratios in one run.

Run: `make bench` (or `.venv/bin/python bench/bench_engine.py`). Needs the test extras (pin).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from pinocchio_oracle import build_pinocchio_model, pinocchio_configuration

from engine import make_inverse, paper_task, plan, plan_batch, table1_robot
from engine.inverses import thin_svd

LAM_MAX, EPSILON = 0.0571, 0.0677


def _best_of(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def pinocchio_reference_plan(pm, frame_id, task, inverse) -> np.ndarray:
    """The planner loop written on Pinocchio: GJM from the frame Jacobian and the centroidal
    momentum matrix, the same adaptive inverse, free-flyer integration with pin.integrate."""
    import pinocchio as pin

    data = pm.createData()
    q_pin = pinocchio_configuration(task.q0, np.zeros(3), np.eye(3))
    twists = task.step_twists()
    qs = np.empty((task.n_steps + 1, task.q0.shape[0]))
    for k in range(task.n_steps + 1):
        pin.forwardKinematics(pm, data, q_pin)
        J = pin.computeFrameJacobian(pm, data, q_pin, frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        Ag = pin.computeCentroidalMap(pm, data, q_pin)
        base_map = -np.linalg.solve(Ag[:, :6], Ag[:, 6:])
        J_g = J[:, 6:] + J[:, :6] @ base_map
        qd = inverse.solve(J_g, twists[k], thin_svd(J_g)).qd
        qs[k] = q_pin[7:]
        v = np.concatenate([base_map @ qd, qd])
        q_pin = pin.integrate(pm, q_pin, v * task.dt)
    return qs


def main() -> None:
    model = table1_robot()
    task = paper_task(model)
    steps = task.n_steps + 1
    inverse = make_inverse("adaptive", lambda_max=LAM_MAX, epsilon=EPSILON)
    rows = []

    t_plan = _best_of(lambda: plan(model, task, inverse), 5) / steps
    rows.append(("plan (one plan)", 1, t_plan))
    per_step = {}
    for batch in (1, 16, 64, 256):
        params = {"lambda_max": np.full(batch, LAM_MAX), "epsilon": np.full(batch, EPSILON)}
        t = _best_of(lambda params=params: plan_batch(model, task, "adaptive", params), 3 if batch < 256 else 2)
        per_step[batch] = t / (batch * steps)
        rows.append((f"plan_batch B={batch}", batch, per_step[batch]))

    pm, fid = build_pinocchio_model(model)
    ref_q = pinocchio_reference_plan(pm, fid, task, inverse)
    t_pin = _best_of(lambda: pinocchio_reference_plan(pm, fid, task, inverse), 5) / steps
    rows.append(("pinocchio loop (one plan)", 1, t_pin))

    ours = plan(model, task, inverse)
    agreement = float(np.abs(ours.q - ref_q).max())

    print(f"paper task: {steps} samples per plan, adaptive damping ({LAM_MAX}, {EPSILON})")
    print(f"{'variant':28s} {'batch':>5s} {'us/plan-step':>13s} {'speed-up vs pinocchio':>22s}")
    for name, batch, t in rows:
        print(f"{name:28s} {batch:5d} {t * 1e6:13.2f} {t_pin / t:22.1f}")
    print(
        f"plan_batch B=64: {per_step[64] * 1e6:.2f} us/plan-step (target <= 2), "
        f"{t_pin / per_step[64]:.1f}x the pinocchio loop (target >= 10)"
    )
    print(f"joint angles, engine vs pinocchio loop: max difference {agreement:.2e} rad")


if __name__ == "__main__":
    main()
