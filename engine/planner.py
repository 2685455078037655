"""Velocity-level Cartesian planner of the paper's Figure 2: thin Python wrappers over the
compiled step loop :func:`engine.kernels.plan.simulate`.

At each sample ``t_k`` (k = 0..N): kinematics and GJM at the current state, commanded twist
(the path's mean twist over the step, plus ``feedback_gain * pose_error`` if asked), robust
inverse -> joint rates ``qd_k``; then ``q_{k+1} = q_k + qd_k dt``, the base attitude integrated
over the step along that linear joint motion (fourth-order Magnus on the momentum-conserving
base rate), and the base position from the fixed system centre of mass (linear momentum stays
exactly zero). :func:`plan` keeps every sample; :func:`plan_batch` (and the GA) keep only the
running metrics, so their memory does not grow with the number of steps, and spread the
parameter sets over threads (the kernels release the GIL).

A task tracks the pose (6 rows of the GJM) or the position only (3 rows); a redundant arm (more
joints than that) may add a secondary objective in the null space (:mod:`engine.redundancy`).
A plan fails, with a message, when a joint leaves its position limits.

Every kept plan carries the dynamics of its executed trajectory (the clamped cubic spline
through its joint samples, :mod:`engine.executed`): joint accelerations, joint torques (forces
for prismatic joints) and the wrench the arm exerts on the carrier, computed in the compiled
step loop after the last step. Metrics-only evaluations compute the torque peaks only when the
robot has an effort limit (:attr:`engine.model.RobotModel.effort_limited`); a plan over a limit
fails, and its ``B`` is infinite.
"""

from __future__ import annotations

import itertools
import math
import os
import threading
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cache, cached_property
from typing import Any, Protocol

import numpy as np

from engine.errors import ParameterError
from engine.geometry import Geometry, build_geometry
from engine.inverses import Inverse, kernel_param_rows, make_inverse, method_spec
from engine.kernels import dynamics as dynamics_kernels
from engine.kernels import plan as plan_kernels
from engine.kernels import redundancy as redundancy_kernels
from engine.metrics import Column, Metrics, Objective, batch_metrics
from engine.model import RobotModel
from engine.redundancy import SecondaryObjective, joint_centres
from engine.spatial import FloatArray, matrix_to_quaternion
from engine.trajectory import TRACKS, CartesianTask

#: Default tolerances on the final pose for a plan to count as reaching its target. Loose on
#: purpose: open-loop damped plans of the paper's task end within about 5 mm and 2 deg.
POSITION_TOLERANCE_M = 0.05
ATTITUDE_TOLERANCE_RAD = math.radians(5.0)

#: Parameter sets of one method: ``{name: (B,) values}`` or a list of ``{name: value}``.
ParamSets = Mapping[str, Sequence[float] | FloatArray] | Sequence[Mapping[str, float]]


def default_threads() -> int:
    """Threads for batched evaluation: ``SPACEARM_ENGINE_THREADS`` if set, else the CPU count."""
    configured = os.environ.get("SPACEARM_ENGINE_THREADS", "")
    if configured.strip():
        return max(1, int(configured))
    return max(1, os.cpu_count() or 1)


_POOL_LOCK = threading.Lock()
_POOL: tuple[int, int, ThreadPoolExecutor] | None = None  # (pid, threads, pool)


def _pool(threads: int) -> ThreadPoolExecutor:
    """A process-wide thread pool (made again after a fork, whose child has no threads)."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL[0] != os.getpid() or _POOL[1] < threads:
            _POOL = (os.getpid(), threads, ThreadPoolExecutor(max_workers=threads, thread_name_prefix="spacearm-plan"))
        return _POOL[2]


def _joint_value(model: RobotModel, j: int, value: float) -> str:
    """A joint position for messages: deg for a revolute joint, m for a prismatic one."""
    return f"{value:.4g} m" if model.links[j].prismatic else f"{math.degrees(value):.4g} deg"


def _effort_value(model: RobotModel, j: int, value: float) -> str:
    """A joint effort for messages: N m for a revolute joint, N for a prismatic one."""
    return f"{value:.4g} N" if model.links[j].prismatic else f"{value:.4g} N m"


def check_task(model: RobotModel, task: CartesianTask) -> None:
    """Whether ``model`` can run ``task``: one start value per joint, within the joint's
    position limits, and at least as many joints as the task tracks (6 for a pose, 3 for a
    position). Raises ``ParameterError`` naming the task field (``q0``, ``q0[j]``, ``tracks``)."""
    n = model.n_joints
    if task.q0.shape != (n,):
        raise ParameterError("q0", f"task has {task.q0.shape[0]} joint angles, robot has {n} joints")
    rows = TRACKS[task.tracks]
    if n < rows:
        other = " (track 'position' instead)" if task.tracks == "pose" and n >= 3 else ""
        raise ParameterError(
            "tracks", f"a {task.tracks} task needs at least {rows} joints; this robot has {n}, so it cannot follow it{other}"
        )
    if not model.limited:
        return
    outside = (task.q0 < model.lower_limits) | (task.q0 > model.upper_limits)
    for j in map(int, np.flatnonzero(outside)):
        lo, hi = model.lower_limits[j], model.upper_limits[j]
        raise ParameterError(
            f"q0[{j}]",
            f"{_joint_value(model, j, task.q0[j])} is outside the limits of joint {j + 1} ({model.joint_names[j]}): "
            f"[{_joint_value(model, j, lo)}, {_joint_value(model, j, hi)}]",
        )


@dataclass(frozen=True)
class PlanOptions:
    """How plans are run and judged, built once at the boundary and passed down: the pose
    feedback gain (1/s), how ``B`` is formed, the null-space objective of a redundant arm and the
    tolerances of the verdict (m, rad)."""

    feedback_gain: float = 0.0
    objective: Objective = field(default_factory=Objective)
    secondary: SecondaryObjective | None = None
    position_tolerance: float = POSITION_TOLERANCE_M
    attitude_tolerance: float = ATTITUDE_TOLERANCE_RAD

    def __post_init__(self) -> None:
        if not math.isfinite(self.feedback_gain) or self.feedback_gain < 0.0:
            raise ParameterError("feedback_gain", "must be finite and >= 0")
        for name in ("position_tolerance", "attitude_tolerance"):
            if not getattr(self, name) > 0.0:
                raise ParameterError(name, "must be > 0")

    @classmethod
    def of(
        cls,
        *,
        weights: tuple[float, float] | None = None,
        aggregation: str | None = None,
        attitude_term: str | None = None,
        **fields: Any,
    ) -> PlanOptions:
        """Options from keywords: the objective's (``weights``, ``aggregation``,
        ``attitude_term``) and this class's own; what is not given keeps its default."""
        if weights is not None or aggregation is not None or attitude_term is not None:
            default = Objective()
            fields["objective"] = Objective(
                weights if weights is not None else default.weights,
                aggregation if aggregation is not None else default.aggregation,
                attitude_term if attitude_term is not None else default.attitude_term,
            )
        return cls(**fields)


class Stop(Protocol):
    """Anything that says whether to stop (a ``threading.Event``, a tuning termination)."""

    def is_set(self) -> bool: ...


@dataclass(frozen=True)
class PlanSetup:
    """A task the robot can run, with the options it is planned with: checked once (by
    :func:`check_task`; errors name ``task.<field>`` or the option), then planned with any number
    of inverses and parameter sets."""

    model: RobotModel
    task: CartesianTask
    options: PlanOptions = field(default_factory=PlanOptions)
    #: The robot that moves when it differs from the controller's ``model`` (a sampled robot of
    #: :mod:`engine.uncertainty`; set by :meth:`under`), and its joints at the start.
    plant: RobotModel | None = field(default=None, compare=False)
    start: FloatArray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        try:
            check_task(self.model, self.task)
        except ParameterError as exc:
            raise exc.within("task") from None
        rows = TRACKS[self.task.tracks]
        if self.options.secondary is not None and self.model.n_joints <= rows:
            raise ParameterError(
                "secondary",
                f"a secondary objective needs a redundant arm: more joints than the {rows} the {self.task.tracks} task "
                f"tracks (this robot has {self.model.n_joints})",
            )
        if self.task.scene.obstacles and not self.model.has_geometry:
            raise ParameterError(
                "task.scene.obstacles",
                "the robot has no collision shapes (collision_radius_m or collision_shapes on its links, collision_box "
                "or collision_shapes on its base): nothing can be checked against the obstacles",
            )
        secondary = self.options.secondary
        if secondary is not None and secondary.objective_id == redundancy_kernels.CLEARANCE and not self.geometry.active:
            raise ParameterError(
                "secondary", "the clearance objective needs collision geometry: shapes on the robot (and obstacles)"
            )

    @classmethod
    def of_tasks(cls, model: RobotModel, tasks: Sequence[CartesianTask], options: PlanOptions) -> list[PlanSetup]:
        """The setup of each task (several tasks of one tuning or landscape): a task's error names
        it by its index (``tasks[2].q0``)."""
        setups = []
        for i, task in enumerate(tasks):
            try:
                setups.append(cls(model, task, options))
            except ParameterError as exc:
                if exc.field.startswith("task."):
                    raise ParameterError(f"tasks[{i}]{exc.field[4:]}", exc.reason) from None
                raise
        return setups

    def retimed(self, duration: float) -> PlanSetup:
        """The same setup with the task's path retimed to ``duration`` s (not checked again: the
        robot, the start and the limits are the same)."""
        return self._copy(task=self.task.with_duration(duration))

    def under(self, plant: RobotModel, start: FloatArray) -> PlanSetup:
        """The same setup run on ``plant`` from joints ``start (n,)`` while the controller keeps
        this setup's model (same task and path; not checked again: a start outside the limits is
        found by the plan)."""
        # a writable copy: a read-only start (a task's q0 is one) is another type to numba, for
        # which it would compile the whole step loop again
        return self._copy(plant=plant, start=np.array(start, dtype=float))

    def _copy(self, **values: Any) -> PlanSetup:
        setup = object.__new__(PlanSetup)
        fields = {"model": self.model, "task": self.task, "options": self.options, "plant": self.plant, "start": self.start}
        for name, value in {**fields, **values}.items():
            object.__setattr__(setup, name, value)
        return setup

    @property
    def robot(self) -> RobotModel:
        """The robot that moves: the plant when there is one, else the model."""
        return self.plant if self.plant is not None else self.model

    @cached_property
    def geometry(self) -> Geometry:
        """The robot's shapes and the task's obstacles as the kernels take them, with the pairs
        that are checked (none without shapes)."""
        model = self.robot
        return build_geometry(
            [link.shapes for link in model.links], model.base.shapes, [link.name for link in model.links], self.task.scene
        )

    @cached_property
    def speed_limits(self) -> FloatArray:
        """``(n,)`` each joint's speed limit: rad/s for revolute joints, m/s for prismatic ones."""
        task = self.task
        return np.where(self.model.prismatic, task.linear_joint_speed_limit, task.joint_speed_limit).astype(float)

    @cached_property
    def _args(self) -> tuple[Any, ...]:
        task, secondary = self.task, self.options.secondary
        samples = task.samples
        q0 = np.array(task.q0, dtype=float)
        return (
            self.model.chain,
            self.robot.chain,
            q0 if self.start is None else self.start,
            samples.twists,
            samples.p_des,
            samples.A_des,
            float(task.dt),
            float(self.options.feedback_gain),
        ), (
            int(TRACKS[task.tracks]),
            int(secondary.objective_id if secondary is not None else redundancy_kernels.NONE),
            float(secondary.gain if secondary is not None else 0.0),
            joint_centres(self.model, q0) if secondary is not None else q0,  # only the joint centering reads it
            self.speed_limits,
        )

    def kernel_args(
        self, inverse: Inverse, params: FloatArray, *, record: bool = False, given: FloatArray | None = None
    ) -> tuple[object, ...]:
        """The leading arguments of the planner kernels (always of the same types, so each kernel
        is compiled once) for ``inverse`` with the parameter rows ``params``; the dynamics are
        computed for a kept plan (``record``) and, for metrics only, when the robot has an
        effort limit. ``given (N+1, n)``: joint rates applied instead of the inverse's (an
        open-loop replay)."""
        head, tail = self._args
        geometry = self.geometry.kernel_args()
        # a writable copy, as the start in under(): a read-only array would compile the loop again
        rates = np.empty((0, self.model.n_joints)) if given is None else np.array(given, dtype=float)
        return (*head, int(inverse.method_id), params, *tail, bool(record or self.model.effort_limited), geometry, rates)

    def metrics(self, raw: FloatArray) -> Metrics[Column]:
        """The metrics of the kernel's rows ``raw (B, N_METRICS)`` of plans of this setup."""
        task = self.task
        return batch_metrics(
            raw,
            task.joint_speed_limit,
            self.options.objective,
            linear_joint_speed_limit=task.linear_joint_speed_limit,
            tracks=task.tracks,
            clearance=task.scene.clearance,
            pair_names=self.geometry.names,
        )


def _trace_arrays(n_samples: int, n: int, rows: int) -> tuple[FloatArray, ...]:
    m = min(rows, n)
    return (
        np.empty((n_samples, n)),
        np.empty((n_samples, n)),
        np.empty((n_samples, 3)),
        np.empty((n_samples, 3, 3)),
        np.empty((n_samples, 3)),
        np.empty((n_samples, 3, 3)),
        np.empty((n_samples, m)),
        np.empty(n_samples),
        np.empty((n_samples, m)),
        np.empty(n_samples),
        np.empty(n_samples),
        np.full(n_samples, np.nan),
        np.full(n_samples, -1.0),
    )


def _kept(
    setup: PlanSetup, inverse: Inverse, given: FloatArray | None = None
) -> tuple[FloatArray, tuple[FloatArray, ...], tuple[FloatArray, ...]]:
    """One plan of ``setup`` (the first parameter set of ``inverse``; ``given`` joint rates instead
    of its own, if any) with every sample kept: the kernel's metrics row ``(N_METRICS,)``, the
    trace and the executed trajectory's dynamics buffers."""
    count = setup.task.n_steps + 1
    n = setup.model.n_joints
    trace = _trace_arrays(count, n, TRACKS[setup.task.tracks])
    t_spline, _, qd_spline, qdd, tau, force, torque = dynamics_kernels.trajectory_buffers(count, n, count)
    dyn = (t_spline, trace[0], qd_spline, qdd, tau, force, torque)  # the spline runs through the trace's samples
    raw = np.empty((1, plan_kernels.N_METRICS))
    args = setup.kernel_args(inverse, kernel_param_rows(inverse, 1), record=True, given=given)
    plan_kernels.simulate(*args, trace, dyn, 0, 1, raw)
    return raw[0], trace, dyn


@cache
def _no_samples(n: int, rows: int) -> tuple[tuple[FloatArray, ...], tuple[FloatArray, ...]]:
    """The trace and dynamics buffers of evaluations that keep metrics only: arrays of no rows
    (never written, so every thread shares them; the kernel makes its own scratch)."""
    return _trace_arrays(0, n, rows), tuple(dynamics_kernels.trajectory_buffers(0, n, 0))


def _for_each(count: int, fn: Callable[[int], None], threads: int | None) -> None:
    """``fn(i)`` for ``i`` in ``range(count)``, spread over ``threads`` threads (default
    :func:`default_threads`)."""
    workers = max(1, threads if threads is not None else default_threads())
    if workers == 1 or count == 1:
        for i in range(count):
            fn(i)
        return
    for f in [_pool(workers).submit(fn, i) for i in range(count)]:
        f.result()


def _clearance_problem(metrics: Metrics[float], geometry: Geometry | None) -> str:
    """The verdict's words for a plan that came closer than the clearance: the pair, the time
    and the distance (negative: the shapes overlap)."""
    pair = int(metrics.collision_pair)
    names = " and ".join(geometry.pair_names(pair)) if geometry is not None else f"pair {pair}"
    d = float(metrics.collision_distance)
    what = f"overlap by {-d * 1e3:.4g} mm" if d < 0.0 else f"come within {d * 1e3:.4g} mm"
    return f"clearance broken: {names} {what} at t = {metrics.time_collision:g} s (clearance {metrics.clearance * 1e3:.4g} mm)"


def _effort_problem(metrics: Metrics[float], model: RobotModel | None) -> str:
    """The verdict's words for a plan over an effort limit: the joint, its largest torque
    (force) against its limit, and when it first went over."""
    j = int(metrics.torque_limit_joint)
    if model is None:
        return f"joint torque limit broken: joint {j + 1} first over its limit at t = {metrics.time_torque_limit_exceeded:g} s"
    what = "force" if model.links[j].prismatic else "torque"
    return (
        f"joint {what} limit broken: joint {j + 1} ({model.joint_names[j]}) needs up to "
        f"{_effort_value(model, j, metrics.torque_limit_peak)} (limit {_effort_value(model, j, model.effort_limits[j])}), "
        f"first over it at t = {metrics.time_torque_limit_exceeded:g} s"
    )


def _verdict(
    metrics: Metrics[float], options: PlanOptions, model: RobotModel | None = None, geometry: Geometry | None = None
) -> tuple[bool, str]:
    position_tolerance, attitude_tolerance = options.position_tolerance, options.attitude_tolerance
    problems = []
    if not metrics.finite:
        problems.append(f"the plan diverged at t = {metrics.time_diverged:g} s (non-finite joint rates or poses)")
    else:
        pose = metrics.tracks == "pose"
        if metrics.position_error_final > position_tolerance or (pose and metrics.attitude_error_final > attitude_tolerance):
            if pose:
                problems.append(
                    f"target not reached: final errors {metrics.position_error_final:.4g} m and "
                    f"{math.degrees(metrics.attitude_error_final):.3g} deg exceed the tolerances "
                    f"{position_tolerance:g} m and {math.degrees(attitude_tolerance):.3g} deg"
                )
            else:
                problems.append(
                    f"target not reached: final position error {metrics.position_error_final:.4g} m exceeds the "
                    f"tolerance {position_tolerance:g} m"
                )
        elif metrics.position_error_max > position_tolerance or (pose and metrics.attitude_error_max > attitude_tolerance):
            if pose:
                problems.append(
                    f"path not tracked: errors up to {metrics.position_error_max:.4g} m and "
                    f"{math.degrees(metrics.attitude_error_max):.3g} deg exceed the tolerances "
                    f"{position_tolerance:g} m and {math.degrees(attitude_tolerance):.3g} deg"
                )
            else:
                problems.append(
                    f"path not tracked: position errors up to {metrics.position_error_max:.4g} m exceed the "
                    f"tolerance {position_tolerance:g} m"
                )
        if metrics.max_joint_speed > metrics.joint_speed_limit:
            problems.append(
                f"joint speed limit broken: {metrics.max_joint_speed_deg_s:.4g} deg/s on joint "
                f"{metrics.max_joint_speed_joint + 1} (limit {math.degrees(metrics.joint_speed_limit):.4g} deg/s)"
            )
        if metrics.max_linear_joint_speed > metrics.linear_joint_speed_limit:
            problems.append(
                f"linear joint speed limit broken: {metrics.max_linear_joint_speed:.4g} m/s on joint "
                f"{metrics.max_linear_joint_speed_joint + 1} (limit {metrics.linear_joint_speed_limit:.4g} m/s)"
            )
        if not metrics.position_limits_respected:
            j = int(metrics.position_limit_joint)
            where = f"joint {j + 1}"
            if model is not None:
                lo, hi = model.lower_limits[j], model.upper_limits[j]
                where += (
                    f" ({model.joint_names[j]}) left its position limits [{_joint_value(model, j, lo)}, "
                    f"{_joint_value(model, j, hi)}] at t = {metrics.time_position_limit_left:g} s, by up to "
                    f"{_joint_value(model, j, metrics.position_limit_excess)}"
                )
            else:
                where += f" left its position limits at t = {metrics.time_position_limit_left:g} s"
            problems.append(where)
        if not metrics.joint_torque_limit_respected:
            problems.append(_effort_problem(metrics, model))
    if not metrics.clearance_respected:  # also reported for a plan that diverged after the contact
        problems.append(_clearance_problem(metrics, geometry))
    if problems:
        return False, "; ".join(problems)
    return True, "ok"


def _where(
    result_t: FloatArray,
    position_error: FloatArray,
    attitude_error: FloatArray,
    qd: FloatArray,
    p_des: FloatArray,
    A_des: FloatArray,
    prismatic: np.ndarray,
    speed_limits: tuple[float, float],
    position_tolerance: float,
    attitude_tolerance: float,
    efforts: FloatArray | None = None,
    effort_limits: FloatArray | None = None,
) -> str:
    """Where a failed plan first went wrong: the first sample that is not finite, off the path
    by more than the tolerances (``attitude_tolerance`` inf for a position task), over a joint's
    speed limit (``speed_limits``: rad/s for revolute, m/s for ``prismatic (n,)`` joints) or,
    given ``efforts (N+1, n)``, over a joint's ``effort_limits (n,)``, with the desired pose
    there."""
    limits = np.where(prismatic, speed_limits[1], speed_limits[0])
    over = np.abs(qd) / limits
    worst = np.max(over, axis=1)
    if efforts is not None and effort_limits is not None:
        heavy = np.where(np.isfinite(effort_limits), np.abs(efforts) / effort_limits, 0.0)
        heavy = np.where(np.isnan(heavy), 0.0, heavy)  # a diverged plan's rows: its stop is reported
    else:
        heavy = np.zeros_like(over)
    strained = np.max(heavy, axis=1)
    bad = ~((position_error <= position_tolerance) & (attitude_error <= attitude_tolerance) & (worst <= 1.0) & (strained <= 1.0))
    if not np.any(bad):
        return ""
    k = int(np.argmax(bad))
    if not (np.isfinite(position_error[k]) and np.isfinite(worst[k])):
        what = "the plan stopped"
    elif worst[k] > 1.0:
        j = int(np.argmax(over[k]))
        speed = f"{abs(qd[k, j]):.4g} m/s" if prismatic[j] else f"{math.degrees(abs(qd[k, j])):.4g} deg/s"
        what = f"joint {j + 1} reached {speed}"
    elif efforts is not None and strained[k] > 1.0:
        j = int(np.argmax(heavy[k]))
        effort = f"{abs(efforts[k, j]):.4g} N" if prismatic[j] else f"{abs(efforts[k, j]):.4g} N m"
        what = f"joint {j + 1} needed {effort}"
    else:
        what = f"the errors reached {position_error[k]:.4g} m and {math.degrees(attitude_error[k]):.3g} deg"
    position = ", ".join(f"{x:.4g}" for x in p_des[k])
    quaternion = ", ".join(f"{x:.4g}" for x in matrix_to_quaternion(A_des[k]))
    return (
        f"first failed at t = {result_t[k]:g} s ({what}), desired pose: position [{position}] m, "
        f"attitude quaternion [w, x, y, z] [{quaternion}]"
    )


@dataclass(frozen=True)
class PlanResult:
    """A planned trajectory; arrays are time-major with ``N + 1`` samples.

    ``qd[k]`` is the joint rate commanded over ``[t_k, t_{k+1}]`` (the last one is the rate
    commanded at the end, zero without feedback). ``clearance`` is the smallest distance of the
    checked pairs at each sample (:mod:`engine.geometry`; the metrics also count the motion
    between samples). ``damping`` is the effective damping per
    singular direction (see :mod:`engine.inverses`). The dynamics are those of the executed
    trajectory (:mod:`engine.executed`: the clamped cubic spline through ``q``, from rest to the
    last commanded rate) at the samples; a plan that diverged has none (NaN). After a
    divergence the samples are NaN.
    """

    inverse: Inverse
    options: PlanOptions
    t: FloatArray  # (N+1,) s
    q: FloatArray  # (N+1, n) rad
    qd: FloatArray  # (N+1, n) rad/s
    base_position: FloatArray  # (N+1, 3) m
    base_attitude: FloatArray  # (N+1, 3, 3)
    ee_position: FloatArray  # (N+1, 3) m
    ee_attitude: FloatArray  # (N+1, 3, 3)
    ee_position_desired: FloatArray  # (N+1, 3) m
    ee_attitude_desired: FloatArray  # (N+1, 3, 3)
    ee_twist_desired: FloatArray  # (N+1, 6) instantaneous desired [v; w], m/s and rad/s
    position_error: FloatArray  # (N+1,) m
    attitude_error: FloatArray  # (N+1,) rad
    singular_values: FloatArray  # (N+1, m) descending
    det_J_g: FloatArray  # (N+1,) nan unless the GJM is square
    damping: FloatArray  # (N+1, m)
    joint_accelerations: FloatArray  # (N+1, n) rad/s^2 (m/s^2 for prismatic joints), executed trajectory
    joint_torques: FloatArray  # (N+1, n) N m (N for prismatic joints)
    mount_force: FloatArray  # (N+1, 3) N, exerted by the arm on the carrier, carrier frame
    mount_torque: FloatArray  # (N+1, 3) N m, about joint 1's origin, carrier frame
    clearance: FloatArray  # (N+1,) m, the smallest distance of any checked pair (NaN without geometry)
    clearance_pair: tuple[tuple[str, str] | None, ...]  # (N+1,) that pair's owners, None without one
    metrics: Metrics[float]
    success: bool
    message: str
    task: CartesianTask = field(repr=False)

    @property
    def method(self) -> str:
        return self.inverse.name

    @property
    def params(self) -> dict[str, float]:
        return self.inverse.scalar_params()

    @property
    def feedback_gain(self) -> float:
        return self.options.feedback_gain

    @property
    def secondary(self) -> SecondaryObjective | None:
        return self.options.secondary


def plan(
    model: RobotModel, task: CartesianTask, inverse: Inverse, options: PlanOptions | None = None, **option_fields: Any
) -> PlanResult:
    """Plan ``task`` with ``inverse`` (options: a :class:`PlanOptions`, or its keywords, see
    :meth:`PlanOptions.of`). ``success`` is false (with a message) if the plan diverged, misses
    the target by more than the tolerances (the attitude only for a pose task), breaks a joint
    speed limit or leaves a joint's position limits; the arrays and metrics are returned in every
    case."""
    return run_plan(PlanSetup(model, task, options or PlanOptions.of(**option_fields)), inverse)


def run_plan(setup: PlanSetup, inverse: Inverse) -> PlanResult:
    """The plan of a checked setup (see :func:`plan`), every sample kept."""
    model, task, options = setup.model, setup.task, setup.options
    samples = task.samples
    raw, trace, dyn = _kept(setup, inverse)
    _, _, _, qdd, tau, force, torque = dyn
    metrics = setup.metrics(raw[None]).item(0)
    success, message = _verdict(metrics, options, model, setup.geometry)
    q, qd, base_p, base_A, ee_p, ee_A, sv, det, damping, pos_err, att_err, clearance, clearance_pair = trace
    if not success:
        where = _where(
            samples.t,
            pos_err,
            att_err,
            qd,
            samples.p_des,
            samples.A_des,
            model.prismatic,
            (task.joint_speed_limit, task.linear_joint_speed_limit),
            options.position_tolerance,
            options.attitude_tolerance if task.tracks == "pose" else math.inf,
            tau,
            model.effort_limits,
        )
        message = f"{message}; {where}" if where else message
    return PlanResult(
        inverse=inverse,
        options=options,
        t=samples.t.copy(),
        q=q,
        qd=qd,
        base_position=base_p,
        base_attitude=base_A,
        ee_position=ee_p,
        ee_attitude=ee_A,
        ee_position_desired=samples.p_des.copy(),
        ee_attitude_desired=samples.A_des.copy(),
        ee_twist_desired=samples.twist_des.copy(),
        position_error=pos_err,
        attitude_error=att_err,
        singular_values=sv,
        det_J_g=det,
        damping=damping,
        joint_accelerations=qdd,
        joint_torques=tau,
        mount_force=force,
        mount_torque=torque,
        clearance=clearance,
        clearance_pair=_pair_names(setup.geometry, clearance_pair),
        metrics=metrics,
        success=success,
        message=message,
        task=task,
    )


def _pair_names(geometry: Geometry, pairs: FloatArray) -> tuple[tuple[str, str] | None, ...]:
    """The owners of each sample's nearest pair ``pairs (N+1,)`` (-1: none)."""
    if not geometry.active:
        return (None,) * len(pairs)
    return tuple(geometry.pair_names(p) if p >= 0 else None for p in pairs.astype(int).tolist())


@dataclass(frozen=True)
class BatchResult:
    """Metrics of ``B`` plans of one method; ``params[name]`` is ``(B,)``."""

    method: str
    params: dict[str, FloatArray]
    metrics: Metrics[Column]

    @property
    def objective_b(self) -> FloatArray:
        return self.metrics.objective_b


def stack_params(method: str, params: ParamSets) -> dict[str, FloatArray]:
    """Parameter sets of ``method`` as ``{name: (B,) values}`` (defaults filled in for a list of dicts)."""
    spec = method_spec(method)
    if isinstance(params, Mapping):
        columns = {k: np.atleast_1d(np.asarray(v, dtype=float)) for k, v in params.items()}
    else:
        rows = list(params)
        if not rows:
            raise ParameterError("params", "at least one parameter set is needed")
        defaults = {p.name: p.default for p in spec.params}
        extra = set().union(*(set(r) for r in rows)) - set(defaults)
        if extra:
            raise ParameterError(min(extra), f"unknown parameter(s) {', '.join(sorted(extra))} for {method}")
        columns = {name: np.array([row.get(name, d) for row in rows], dtype=float) for name, d in defaults.items()}
    sizes = {v.shape for v in columns.values()}
    if len(sizes) > 1 or any(len(s) != 1 for s in sizes):
        raise ParameterError("params", "every parameter needs the same number of values (one per plan)")
    return columns


class EvaluationStoppedError(Exception):
    """:func:`evaluate` was stopped (its ``stop`` was set) before every plan was run."""


#: Target work of one piece of a stoppable evaluation (s of one thread): a stop request is
#: honoured after the pieces already running, so within about this long.
STOP_LATENCY_S = 0.05
#: Rough cost of a plan-step per joint (s), to size the pieces (measured: 0.9 to 1.2 µs).
JOINT_STEP_COST_S = 1.2e-6


def evaluate(
    setup: PlanSetup,
    inverse: Inverse,
    batch: int,
    *,
    threads: int | None = None,
    batch_size: int | None = None,
    stop: Stop | None = None,
) -> FloatArray:
    """The kernel's metrics rows ``(batch, N_METRICS)`` of ``batch`` parameter sets of
    ``inverse`` (array parameters of shape ``(batch,)``), no traces kept. The sets are split
    into pieces of ``batch_size`` (default: about four per thread, for balance: diverging
    plans end early) run on ``threads`` threads (default :func:`default_threads`).

    With a ``stop`` the pieces are small (about :data:`STOP_LATENCY_S` of work each) and a piece
    that has not started when ``stop`` is set is skipped: :class:`EvaluationStoppedError` is
    raised once the running ones end."""
    args = setup.kernel_args(inverse, kernel_param_rows(inverse, batch))
    none_kept = _no_samples(setup.model.n_joints, TRACKS[setup.task.tracks])
    out = np.empty((batch, plan_kernels.N_METRICS))
    workers = max(1, threads if threads is not None else default_threads())
    size = batch_size or max(1, math.ceil(batch / (4 * workers)))
    if stop is not None and batch_size is None:
        plan_cost = (setup.task.n_steps + 1) * setup.model.n_joints * JOINT_STEP_COST_S
        size = max(1, min(size, int(STOP_LATENCY_S / plan_cost)))
    edges = list(range(0, batch, size)) + [batch]

    def piece(start: int, stop_at: int) -> bool:
        if stop is not None and stop.is_set():
            return False
        plan_kernels.simulate(*args, *none_kept, start, stop_at, out)
        return True

    if workers == 1 or len(edges) <= 2:
        done = all([piece(a, b) for a, b in itertools.pairwise(edges)])
    else:
        pool = _pool(workers)
        done = all([f.result() for f in [pool.submit(piece, a, b) for a, b in itertools.pairwise(edges)]])
    if not done:
        raise EvaluationStoppedError("stopped before every plan was run")
    return out


def plan_batch(
    model: RobotModel,
    task: CartesianTask,
    method: str,
    params: ParamSets,
    options: PlanOptions | None = None,
    *,
    batch_size: int | None = None,
    threads: int | None = None,
    stop: Stop | None = None,
    **option_fields: Any,
) -> BatchResult:
    """Plan many parameter sets of ``method`` and return their metrics (no trajectories: the
    memory is proportional to the number of sets, not to the number of steps).

    ``params`` is either ``{name: (B,) values}`` or a list of ``{name: value}`` dicts.
    ``batch_size``, ``threads`` and ``stop``: see :func:`evaluate`; options as for :func:`plan`.
    Each set's result is independent of the batch it runs in.
    """
    setup = PlanSetup(model, task, options or PlanOptions.of(**option_fields))
    columns = stack_params(method, params)
    total = next(iter(columns.values())).shape[0] if columns else max(1, len(params))
    inverse = make_inverse(method, **columns)
    raw = evaluate(setup, inverse, total, threads=threads, batch_size=batch_size, stop=stop)
    return BatchResult(method=method, params=columns, metrics=setup.metrics(raw))


def evaluate_setups(setups: Sequence[PlanSetup], inverse: Inverse, *, threads: int | None = None) -> FloatArray:
    """The kernel's metrics rows ``(len(setups), N_METRICS)`` of one parameter set of ``inverse``
    on each setup (for example one path at several durations), no traces kept, spread over
    ``threads`` threads (default :func:`default_threads`)."""
    params = kernel_param_rows(inverse, 1)
    args = [setup.kernel_args(inverse, params) for setup in setups]
    out = np.empty((len(args), plan_kernels.N_METRICS))

    def run(i: int) -> None:
        setup = setups[i]
        none_kept = _no_samples(setup.model.n_joints, TRACKS[setup.task.tracks])
        plan_kernels.simulate(*args[i], *none_kept, 0, 1, out[i : i + 1])

    _for_each(len(args), run, threads)
    return out


def verdicts(raw: FloatArray, setups: Sequence[PlanSetup]) -> list[tuple[Metrics[float], bool, str]]:
    """Metrics, success and message of each row of :func:`evaluate_setups`."""
    out = []
    for row, setup in zip(raw, setups, strict=True):
        metrics = setup.metrics(row[None]).item(0)
        out.append((metrics, *_verdict(metrics, setup.options, setup.model, setup.geometry)))
    return out


def evaluate_traced(
    setups: Sequence[PlanSetup], inverse: Inverse, *, given: FloatArray | None = None, threads: int | None = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One parameter set of ``inverse`` on each setup (of one task: a plan's sampled robots),
    every sample kept but only the tracking errors returned: the kernel's metrics rows
    ``(S, N_METRICS)`` and the position ``(S, N+1)`` m and attitude ``(S, N+1)`` rad errors.
    ``given (N+1, n)``: joint rates applied instead of the inverse's. Spread over ``threads``."""
    count = setups[0].task.n_steps + 1
    raw = np.empty((len(setups), plan_kernels.N_METRICS))
    position, attitude = np.empty((len(setups), count)), np.empty((len(setups), count))

    def run(i: int) -> None:
        raw[i], trace, _ = _kept(setups[i], inverse, given)
        position[i], attitude[i] = trace[9], trace[10]

    _for_each(len(setups), run, threads)
    return raw, position, attitude
