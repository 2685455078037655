"""The joint trajectory a robot executes from a plan, and its base motion.

A plan (:class:`engine.planner.PlanResult`) gives samples ``q_k`` at ``t_k`` and rates ``qd_k``
held over ``[t_k, t_{k+1}]``: its accelerations are impulses at the samples, so its torques are
not defined. The executed trajectory is the **clamped cubic spline** through ``(t_k, q_k)``
(:mod:`engine.kernels.spline`), which

- passes through every sample, so the plan's tracking at the samples is kept up to the base's
  drift (the base attitude depends on the joint path, not just its end points:
  :func:`executed_motion` integrates it, :func:`replay_executed` measures the change);
- has continuous, finite accelerations (piecewise linear in time, so for the slow motion of a
  space arm the torque peaks sit at the samples), continuous torques and a bounded jerk;
- keeps the plan's mean rates exactly (any interpolant of the samples has the mean rate ``qd_k``
  over step k) and its knot rates are the local average of the neighbouring plan rates to
  ``O(dt^2)``;
- is the smoothest interpolant: among all functions through the samples with the same end
  rates it minimises ``int |qdd|^2 dt`` (Holladay's theorem), the least acceleration effort;
- costs one tridiagonal solve per joint, O(N n), compiled. It is global, but a sample's influence
  decays by ``2 - sqrt(3) ~ 0.27`` per step, so it is local in practice.

Rejected: rates ramped linearly between the samples (C1 only: the torque jumps at every sample;
and to pass through the samples the knot rates must satisfy ``(v_k + v_{k+1}) / 2 = qd_k``, a
recurrence whose alternating mode is not damped, so any mismatch rings to the end); a local
quintic Hermite scheme from finite-difference knot rates and accelerations (C2 and local, but
its acceleration is a cubic in each step that overshoots between the samples, and ``int
|qdd|^2`` is larger).

End conditions: the plan holds the joints still before ``t_0`` and at its last commanded rate
``qd_N`` after ``t_N`` (zero for an open-loop plan of a path that ends at rest), so by default the
spline starts at rest and ends at ``qd_N``: the motion is complete, with no impulse at either
end. (A path that starts at speed, ramp time 0, then has a start transient that decays by 0.27
per step.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.kernels import replay as replay_kernels
from engine.kernels import spline as spline_kernels
from engine.model import RobotModel
from engine.planner import PlanResult
from engine.replay import ATOL, FAILURES, RTOL, ReplayResult, failed_result, summarise
from engine.spatial import FloatArray, matrix_to_quaternion


@dataclass(frozen=True)
class ExecutedTrajectory:
    """A clamped cubic spline through joint samples: knots ``t (N+1,)`` s, positions ``q``,
    knot rates ``qd`` and knot accelerations ``qdd`` ``(N+1, n)`` (rad, rad/s, rad/s^2; m, m/s,
    m/s^2 for prismatic joints). Build with :func:`executed_trajectory` or :func:`from_plan`."""

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])

    def at(self, times: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)``, each ``(M, n)``, at ``times (M,)`` s within ``[t_0, t_N]``."""
        times = np.ascontiguousarray(times, dtype=float).reshape(-1)
        if times.size and not (times.min() >= self.t[0] and times.max() <= self.t[-1]):
            raise ParameterError("times", f"must lie within [{self.t[0]:g}, {self.t[-1]:g}] s")
        shape = (times.shape[0], self.q.shape[1])
        q, qd, qdd = np.empty(shape), np.empty(shape), np.empty(shape)
        spline_kernels.evaluate_spline(self.t, self.q, self.qd, self.qdd, times, q, qd, qdd)
        return q, qd, qdd

    def pieces(self, grid: FloatArray) -> FloatArray:
        """Taylor coefficients ``(G-1, 4, n)`` of the spline on each interval of ``grid (G,)``
        (increasing, within the knots, every knot included): ``q(grid_i + s) = sum_p c[i, p]
        s^p``, as :func:`engine.kernels.replay.integrate_motion` takes them."""
        q, qd, qdd = self.at(grid[:-1])
        k = np.clip(np.searchsorted(self.t, grid[:-1], side="right") - 1, 0, self.t.shape[0] - 2)
        jerk = (self.qdd[k + 1] - self.qdd[k]) / (self.t[k + 1] - self.t[k])[:, None]
        return np.ascontiguousarray(np.stack([q, qd, 0.5 * qdd, jerk / 6.0], axis=1))


def executed_trajectory(
    t: ArrayLike, q: ArrayLike, start_rate: ArrayLike | None = None, end_rate: ArrayLike | None = None
) -> ExecutedTrajectory:
    """The clamped cubic spline through ``q (N+1, n)`` at increasing ``t (N+1,)`` (N >= 1), with
    rates ``start_rate`` and ``end_rate (n,)`` at the ends (default: zero)."""
    # copies, writable: a read-only array (a stored plan's, a broadcast rate) is another type to
    # numba, which would compile the spline again at run time
    t = np.array(t, dtype=float)
    q = np.array(q, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2 or q.ndim != 2 or q.shape[0] != t.shape[0]:
        raise ParameterError("t", f"expected N+1 >= 2 times and (N+1, n) positions, got {t.shape} and {q.shape}")
    if not np.all(np.diff(t) > 0.0):
        raise ParameterError("t", "sample times must increase")
    n = q.shape[1]
    v0 = np.zeros(n) if start_rate is None else np.array(np.broadcast_to(start_rate, (n,)), dtype=float)
    v1 = np.zeros(n) if end_rate is None else np.array(np.broadcast_to(end_rate, (n,)), dtype=float)
    qd = np.empty_like(q)
    qdd = np.empty_like(q)
    spline_kernels.clamped_spline(t, q, v0, v1, qd, qdd)
    return ExecutedTrajectory(t=t, q=q, qd=qd, qdd=qdd)


def from_plan(plan_result: PlanResult) -> ExecutedTrajectory:
    """The executed trajectory of a plan: from rest at ``t_0`` to the plan's last commanded rate
    ``qd_N`` at ``t_N`` (see the module docstring)."""
    return executed_trajectory(plan_result.t, plan_result.q, None, plan_result.qd[-1])


@dataclass(frozen=True)
class ExecutedMotion:
    """The motion along an executed trajectory, ``M`` samples: joints, base (integrated with
    zero momentum) and end effector, world frame, SI units."""

    t: FloatArray  # (M,) s
    q: FloatArray  # (M, n)
    qd: FloatArray  # (M, n)
    base_position: FloatArray  # (M, 3) m, base CoM
    base_attitude: FloatArray  # (M, 3, 3)
    ee_position: FloatArray  # (M, 3) m
    ee_attitude: FloatArray  # (M, 3, 3)
    linear_momentum_residual: FloatArray  # (M,) N s
    angular_momentum_residual: FloatArray  # (M,) N m s
    com: FloatArray  # (M, 3) m, system CoM
    n_function_evaluations: int
    success: bool
    message: str


def executed_motion(
    model: RobotModel,
    trajectory: ExecutedTrajectory,
    base_position: ArrayLike,
    base_attitude: ArrayLike,
    times: ArrayLike | None = None,
    *,
    rtol: float = RTOL,
    atol: float = ATOL,
) -> ExecutedMotion:
    """Integrate the base along ``trajectory`` from ``base_position (3,)`` m and ``base_attitude
    (3, 3)`` at its first knot (the replay's DOP853 of the 6x6 momentum equations, restarted at
    every knot and requested time), and return the motion at ``times (M,)`` s (default: the
    knots)."""
    knots = trajectory.t
    want = knots if times is None else np.ascontiguousarray(times, dtype=float).reshape(-1)
    if want.size and not (want.min() >= knots[0] and want.max() <= knots[-1]):
        raise ParameterError("times", f"must lie within [{knots[0]:g}, {knots[-1]:g}] s")
    grid = np.union1d(knots, want)
    ys = np.empty((grid.shape[0], 7))
    ys[0, :3] = base_position
    ys[0, 3:] = matrix_to_quaternion(np.asarray(base_attitude, dtype=float))
    coef = trajectory.pieces(grid)
    q, qd, _ = trajectory.at(want)
    status, failed, nfev = replay_kernels.integrate_motion(model.chain, grid, coef, ys, float(rtol), float(atol))
    M = want.shape[0]
    ee_p, ee_A, base_A = np.full((M, 3), np.nan), np.full((M, 3, 3), np.nan), np.full((M, 3, 3), np.nan)
    lin, ang, com = np.full(M, np.nan), np.full(M, np.nan), np.full((M, 3), np.nan)
    ok = status == replay_kernels.OK and bool(np.all(np.isfinite(coef)))
    if ok:
        rows = np.ascontiguousarray(ys[np.searchsorted(grid, want)])
        replay_kernels.evaluate_samples(model.chain, q, qd, rows, ee_p, ee_A, base_A, lin, ang, com)
        base_p = rows[:, :3].copy()
        message = "ok"
    else:
        base_p = np.full((M, 3), np.nan)
        why = FAILURES.get(status, "the trajectory is not finite")
        message = f"integration failed at t = {grid[max(failed, 0)]:g} s: {why}"
    return ExecutedMotion(
        t=want,
        q=q,
        qd=qd,
        base_position=base_p,
        base_attitude=base_A,
        ee_position=ee_p,
        ee_attitude=ee_A,
        linear_momentum_residual=lin,
        angular_momentum_residual=ang,
        com=com,
        n_function_evaluations=int(nfev),
        success=ok,
        message=message,
    )


def replay_executed(
    model: RobotModel,
    plan_result: PlanResult,
    trajectory: ExecutedTrajectory | None = None,
    *,
    rtol: float = RTOL,
    atol: float = ATOL,
) -> ReplayResult:
    """How executing ``plan_result`` (by default through :func:`from_plan`) changes its tracking:
    the motion at the plan's samples as a :class:`engine.replay.ReplayResult`, whose
    ``plan_gap_*`` compare the executed end effector with the planned one and ``path_*`` with the
    desired path."""
    t = np.ascontiguousarray(plan_result.t, dtype=float)
    if not (np.all(np.isfinite(plan_result.q)) and np.all(np.isfinite(plan_result.qd))):
        return failed_result(t, "the plan is not finite, nothing to execute")
    trajectory = trajectory or from_plan(plan_result)
    motion = executed_motion(
        model, trajectory, plan_result.base_position[0], plan_result.base_attitude[0], t, rtol=rtol, atol=atol
    )
    if not motion.success:
        return failed_result(t, motion.message, motion.n_function_evaluations)
    return summarise(
        plan_result,
        motion.base_position,
        motion.ee_position,
        motion.ee_attitude,
        motion.base_attitude,
        motion.linear_momentum_residual,
        motion.angular_momentum_residual,
        motion.com,
        motion.n_function_evaluations,
    )
