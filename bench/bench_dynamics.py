"""Joint torques along the paper plan (adaptive damping, lambda_max 0.040, epsilon 0.37,
dt 0.25 s): µs per sample of the compiled inverse dynamics (with and without the kinematics it
needs; the base twist given, the GJM's ``base_map @ qd``, or found from zero momentum in the
recursion), of the executed trajectory's spline, and how executing the plan's spline instead
of its piecewise-constant rates changes the end-effector tracking.

Run: `PYTHONPATH=. .venv/bin/python bench/bench_dynamics.py [--rounds R]` (medians of R rounds).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections.abc import Callable

import numpy as np
from numba import njit

from engine import make_inverse, paper_task, plan, replay, table1_robot
from engine.dynamics import plan_dynamics
from engine.executed import from_plan, replay_executed
from engine.kernels import chain as chain_kernels
from engine.kernels import dynamics as dynamics_kernels
from engine.kernels import spline as spline_kernels


@njit(cache=False)
def _rnea_only(ch, att, com, jpos, jaxis, ee_p, ee_A, twists, qd, qdd, repeats, tau, force, torque, acc, zero_momentum):
    """The per-sample routine alone, on precomputed kinematics (``zero_momentum``: it finds the
    twist, written over ``twists``)."""
    work = dynamics_kernels.dynamics_buffers(qd.shape[1])
    for _ in range(repeats):
        for k in range(qd.shape[0]):
            kin = (att[k], com[k], jpos[k], jaxis[k], ee_p[k], ee_A[k])
            dynamics_kernels.inverse_dynamics(
                ch, kin, twists[k], qd[k], qdd[k], work, tau[k], force[k], torque[k], acc[k], zero_momentum
            )


def _median_us(fn: Callable[[], object], rounds: int, per: int) -> float:
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e6 * statistics.median(times) / per


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=21)
    args = parser.parse_args()
    robot = table1_robot()
    result = plan(robot, paper_task(robot), make_inverse("adaptive", lambda_max=0.040, epsilon=0.37))
    ch = robot.chain
    trajectory = from_plan(result)
    q, qd, qdd = trajectory.q, trajectory.qd, trajectory.qdd
    N1, n = q.shape
    A0, origin = np.ascontiguousarray(result.base_attitude), np.ascontiguousarray(result.base_position)
    tau, force, torque = np.empty((N1, n)), np.empty((N1, 3)), np.empty((N1, 3))
    twist, acc = np.empty((N1, 6)), np.empty((N1, 6))
    J, base_map = np.empty((N1, 6, n)), np.empty((N1, 6, n))
    repeats = 200
    kins = (np.empty((N1, n + 1, 3, 3)), np.empty((N1, n + 1, 3)), np.empty((N1, n, 3)), np.empty((N1, n, 3)))
    ee = (np.empty((N1, 3)), np.empty((N1, 3, 3)))
    chain_kernels.kinematics_many(ch, q, A0, origin, False, *kins, *ee)
    chain_kernels.gjm_many(ch, q, A0, origin, False, J, base_map)
    twists = np.ascontiguousarray(np.einsum("kij,kj->ki", base_map, qd))

    def full() -> None:
        for _ in range(repeats):
            dynamics_kernels.inverse_dynamics_many(ch, q, qd, qdd, A0, origin, tau, force, torque, twist, acc)

    def kinematics() -> None:
        for _ in range(repeats):
            chain_kernels.kinematics_many(ch, q, A0, origin, False, *kins, *ee)

    def kinematics_gjm() -> None:
        for _ in range(repeats):
            chain_kernels.gjm_many(ch, q, A0, origin, False, J, base_map)

    def rnea() -> None:
        _rnea_only(ch, *kins, *ee, twists, qd, qdd, repeats, tau, force, torque, acc, np.bool_(False))

    found = twists.copy()

    def rnea_zero_momentum() -> None:
        _rnea_only(ch, *kins, *ee, found, qd, qdd, repeats, tau, force, torque, acc, np.bool_(True))

    v0, v1 = np.zeros(n), np.ascontiguousarray(result.qd[-1])
    t = np.ascontiguousarray(result.t)
    sd, sdd = np.empty_like(q), np.empty_like(q)

    def spline() -> None:
        for _ in range(repeats):
            spline_kernels.clamped_spline(t, q, v0, v1, sd, sdd)

    for fn in (full, kinematics, kinematics_gjm, rnea, rnea_zero_momentum, spline):  # compile / load
        fn()
    per = repeats * N1
    print(f"paper plan: {N1} samples, {n} joints, success={result.success}")
    print(f"the twist from zero momentum: within {np.abs(found - twists).max():.1e} of the GJM's base_map @ qd")
    print(f"inverse_dynamics_many (kinematics + RNEA, twist from momentum): {_median_us(full, args.rounds, per):.2f} µs/sample")
    print(f"  of which the kinematics (kinematics_many):       {_median_us(kinematics, args.rounds, per):.2f} µs/sample")
    print(f"  the RNEA alone, finding the twist:               {_median_us(rnea_zero_momentum, args.rounds, per):.2f} µs/sample")
    print(f"  the RNEA alone, given the twist:                 {_median_us(rnea, args.rounds, per):.2f} µs/sample")
    print(f"kinematics + GJM (gjm_many), for comparison:     {_median_us(kinematics_gjm, args.rounds, per):.2f} µs/sample")
    print(f"clamped spline (the executed trajectory):        {_median_us(spline, args.rounds, per):.3f} µs/sample")

    planned = replay(robot, result)
    executed = replay_executed(robot, result)
    dynamics = plan_dynamics(robot, result)
    arcsec = math.degrees(1.0) * 3600.0
    print("tracking change, executed spline vs the plan's end effector at the samples:")
    gap_p, gap_A = executed.plan_gap_position_max * 1e6, executed.plan_gap_attitude_max * arcsec
    print(f"  position max {gap_p:.3f} µm, attitude max {gap_A:.3f} arcsec")
    print(f"  base attitude max {executed.base_attitude_gap_max * arcsec:.3f} arcsec")
    print(
        f"  path error max (vs desired): executed {executed.path_position_error_max * 1e3:.4f} mm, "
        f"{math.degrees(executed.path_attitude_error_max):.5f} deg; "
        f"plan replay {planned.path_position_error_max * 1e3:.4f} mm, {math.degrees(planned.path_attitude_error_max):.5f} deg"
    )
    print(f"  replay nfev {executed.n_function_evaluations} (plan replay {planned.n_function_evaluations})")
    print(f"peak |torque| per joint (N m): {np.array2string(dynamics.peak_torques, precision=4)}")
    force, torque = np.linalg.norm(dynamics.mount_force, axis=1).max(), np.linalg.norm(dynamics.mount_torque, axis=1).max()
    print(f"peak |qdd| {np.abs(qdd).max():.4f} rad/s^2; peak mount force {force:.4f} N, mount torque {torque:.4f} N m")


if __name__ == "__main__":
    main()
