"""Cartesian tasks: an initial configuration, a path to follow, a time step and a joint speed
limit; sampled once into what the planner's kernels consume (:class:`PathSamples`).

A task is ``(q0, path, dt, limits, tracks)``; the path carries its own geometry and timing (the
paper's straight line is :class:`engine.paths.LinePath`, built by :meth:`CartesianTask.from_q0`;
other types by :meth:`CartesianTask.along` or :meth:`CartesianTask.following`). Its start and
target poses and its duration are read off the path.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.geometry import Scene
from engine.kernels.so3 import quaternion_of
from engine.kinematics import as_state, forward_kinematics
from engine.model import RobotModel, table1_robot
from engine.paths import PROFILES, LinePath, Path, Profile, make_path
from engine.spatial import FloatArray, rpy_spacedyn_to_matrix

__all__ = [
    "MAX_DURATION_S",
    "MAX_STEPS",
    "MIN_DT_S",
    "PAPER_GA_OPTIMUM",
    "PAPER_Q0_DEG",
    "PAPER_TARGET_POSITION",
    "PAPER_TARGET_QUATERNION",
    "PAPER_TARGET_RPY",
    "PAPER_TASK_PARAMS",
    "PROFILES",
    "TRACKS",
    "CartesianTask",
    "PathSamples",
    "Profile",
    "Tracks",
    "paper_task",
    "start_pose",
]

Tracks = Literal["pose", "position"]
TRACKS: dict[str, int] = {"pose": 6, "position": 3}  # what a task tracks -> rows of the GJM it needs
MAX_DURATION_S = 600.0
MAX_STEPS = 20_000
MIN_DT_S = 1e-4  # 0.1 ms: finer steps add rounding, not accuracy

#: The paper's initial joint angles (deg) and target pose (SpaceDyn RPY, rad).
PAPER_Q0_DEG = (175.0, -60.0, -60.0, 0.0, 210.0, 5.0)
PAPER_TARGET_POSITION = (1.50, 0.0, -0.20)
PAPER_TARGET_RPY = (-3.16, -0.26, -3.14)
#: The target attitude as a quaternion ``[w, x, y, z]`` (12 decimals, as the API's examples show
#: it), by the kernel's Python function: the API's schemas read it when imported (the migration
#: too, and the launcher's children during a first start), which must neither load numba's
#: compiler nor compile a kernel beside ``spacearm compile`` (1.5 s of CPU in each process).
PAPER_TARGET_QUATERNION = tuple(round(float(x), 12) for x in quaternion_of.py_func(rpy_spacedyn_to_matrix(PAPER_TARGET_RPY)))

#: The paper's own GA optimum of the adaptive damping (its section 4), for its exact robot: on this
#: reconstruction of the Table-1 robot (the paper does not give every frame) the plan of the
#: paper's task with it reaches 8.54 deg/s on joint 4 near the singular point, over the 6 deg/s
#: limit. It is the ``adaptive`` method's default, so the paper's values are kept as published.
PAPER_GA_OPTIMUM: dict[str, float] = {"lambda_max": 0.0571, "epsilon": 0.0677}

#: Parameters that succeed on the paper's task on this robot (6 deg/s, the Table-1 torque limits):
#: the GA optima of the README's tuning job (population 20, 20 generations, seed 1), rounded; SVF's
#: default breaks the speed limit too. The web form, ``python -m engine.demo`` and the README's
#: first engine example use them.
PAPER_TASK_PARAMS: dict[str, dict[str, float]] = {
    "adaptive": {"lambda_max": 0.040, "epsilon": 0.37},
    "dls": {"lambda": 0.035},
    "bounded": {"lambda": 0.025},
    "svf": {"sigma0": 0.19, "nu": 75.0},
}


class PathSamples(NamedTuple):
    """A task sampled for the planner (what the kernels consume; do not modify).

    ``t (N+1,)`` s; ``twists (N+1, 6)`` the commanded twist of each step ``[v; w]`` (m/s, rad/s,
    world axes; the mean desired twist over the step, zero at the end); ``p_des (N+1, 3)`` m and
    ``A_des (N+1, 3, 3)`` the desired poses at the samples; ``twist_des (N+1, 6)`` the
    instantaneous desired twist there.
    """

    t: FloatArray
    twists: FloatArray
    p_des: FloatArray
    A_des: FloatArray
    twist_des: FloatArray


@dataclass(frozen=True)
class CartesianTask:
    """A Cartesian task: the initial joint positions ``q0`` (rad, m for prismatic joints), the
    ``path`` the end effector follows (from the end-effector pose at ``q0``), the planner's step
    ``dt`` (s), the joint speed limits and what the planner follows. SI units, rad; attitudes are
    rotation matrices (end effector -> world). The base starts at rest at the origin with identity
    attitude.

    ``tracks`` says what the planner follows: the whole ``"pose"`` (needs 6 joints or more) or
    the ``"position"`` only (3 or more; the attitude path is then reported, not tracked).
    ``joint_speed_limit`` (rad/s) applies to revolute joints, ``linear_joint_speed_limit``
    (m/s, unlimited by default) to prismatic ones. ``scene`` holds the obstacles (world frame)
    and the clearance the plan keeps from them, from the carrier and between links
    (:mod:`engine.geometry`; checked when the robot or the scene has collision shapes)."""

    q0: FloatArray  # (n,) rad
    path: Path
    dt: float = 0.25  # s
    joint_speed_limit: float = math.radians(6.0)  # rad/s, symmetric
    tracks: Tracks = "pose"
    linear_joint_speed_limit: float = math.inf  # m/s, symmetric
    scene: Scene = field(default_factory=Scene)

    def __post_init__(self) -> None:
        q0 = np.array(self.q0, dtype=float).reshape(-1)
        if q0.size == 0 or not np.all(np.isfinite(q0)):
            raise ParameterError("q0", "expected finite joint angles")
        q0.setflags(write=False)
        object.__setattr__(self, "q0", q0)
        for name in ("dt", "joint_speed_limit"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ParameterError(name, "must be finite")
            object.__setattr__(self, name, value)
        if not 0.0 < self.duration <= MAX_DURATION_S:
            raise ParameterError("duration", f"must be in (0, {MAX_DURATION_S:g}] s")
        if not MIN_DT_S <= self.dt <= 1.0:
            raise ParameterError("dt", f"must be in [{MIN_DT_S:g}, 1] s")
        if self.dt > self.duration:
            # one step would cover more than the whole path: the plan would move at the speed of a
            # path dt long, not the one asked for, and pass limits the path itself breaks
            raise ParameterError("dt", f"must not exceed the path's duration, {self.duration:g} s")
        if self.joint_speed_limit <= 0.0:
            raise ParameterError("joint_speed_limit", "must be > 0")
        if self.tracks not in TRACKS:
            raise ParameterError("tracks", f"must be one of {', '.join(TRACKS)}")
        linear = float(self.linear_joint_speed_limit)
        if math.isnan(linear) or linear <= 0.0:
            raise ParameterError("linear_joint_speed_limit", "must be > 0 (inf for no limit)")
        object.__setattr__(self, "linear_joint_speed_limit", linear)
        if self.n_steps > MAX_STEPS:
            raise ParameterError("dt", f"duration / dt gives {self.n_steps} steps, at most {MAX_STEPS} allowed")

    @classmethod
    def from_q0(
        cls,
        model: RobotModel,
        q0: ArrayLike,
        target_position: ArrayLike,
        target_attitude: ArrayLike,
        *,
        duration: float = 15.0,
        ramp_time: float = 1.5,
        profile: Profile = "trapezoidal",
        **options: Any,
    ) -> CartesianTask:
        """The paper's kind of task: the straight line (:class:`LinePath`) from the forward
        kinematics at ``q0`` (base at the origin) to the target pose in ``duration`` s;
        ``options``: ``dt``, the speed limits, ``tracks``."""
        state = as_state(model, q0)
        fk = forward_kinematics(model, state)
        target_p, target_A = np.asarray(target_position, dtype=float), np.asarray(target_attitude, dtype=float)
        line = LinePath(fk.ee_position, fk.ee_attitude, target_p, target_A, duration, ramp_time, profile)
        return cls(q0=state.q, path=line, **options)

    @classmethod
    def following(cls, path: Path, q0: ArrayLike, **options: Any) -> CartesianTask:
        """The task that follows ``path`` from ``q0`` (rad; the path must start at the
        end-effector pose of ``q0``); ``options``: ``dt``, the speed limits, ``tracks``."""
        return cls(q0=np.asarray(q0, dtype=float), path=path, **options)

    @classmethod
    def along(
        cls,
        model: RobotModel,
        q0: ArrayLike,
        kind: str,
        *,
        dt: float = 0.25,
        joint_speed_limit: float = math.radians(6.0),
        **spec: Any,
    ) -> CartesianTask:
        """The task of a path of type ``kind`` (:func:`engine.paths.make_path`, keyword
        arguments ``spec``) starting at the forward kinematics of ``q0`` (rad, base at the
        origin)."""
        position, attitude = start_pose(model, q0)
        return cls.following(make_path(kind, position, attitude, **spec), q0, dt=dt, joint_speed_limit=joint_speed_limit)

    def with_duration(self, duration: float) -> CartesianTask:
        """The same task with its path retimed to ``duration`` s (every speed scaled; a line's
        or an arc's ramp time scales with it)."""
        return dataclasses.replace(self, path=self.path.retimed(duration))

    @property
    def duration(self) -> float:
        """The path's duration, s."""
        return float(self.path.duration)

    @cached_property
    def _ends(self) -> tuple[FloatArray, FloatArray]:
        return self.path.pose(np.array([0.0, self.path.duration]))

    @property
    def start_position(self) -> FloatArray:
        """(3,) m, where the path starts."""
        return self._ends[0][0]

    @property
    def start_attitude(self) -> FloatArray:
        """(3, 3), the path's first attitude."""
        return self._ends[1][0]

    @property
    def target_position(self) -> FloatArray:
        """(3,) m, where the path ends."""
        return self._ends[0][1]

    @property
    def target_attitude(self) -> FloatArray:
        """(3, 3), the path's last attitude."""
        return self._ends[1][1]

    @property
    def n_steps(self) -> int:
        """Number of integration steps; the last sample is at ``n_steps * dt >= duration``."""
        return max(1, math.ceil(self.duration / self.dt - 1e-9))

    def times(self) -> FloatArray:
        """Sample times ``(n_steps + 1,)`` s."""
        return np.arange(self.n_steps + 1) * self.dt

    @property
    def kind(self) -> str:
        """The path type: ``line``, ``waypoints``, ``arc``, ``raster``, ..."""
        return self.path.kind

    def desired_pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(p_d (..., 3), A_d (..., 3, 3))`` at times ``t``."""
        return self.path.pose(t)

    def desired_twist(self, t: ArrayLike) -> FloatArray:
        """Instantaneous desired twist ``[v_e; w_e] (..., 6)`` (m/s, rad/s) at times ``t``."""
        return self.path.twist(t)

    def step_twists(self) -> FloatArray:
        """Commanded twist per sample ``(n_steps + 1, 6)``: the mean desired twist over
        ``[t_k, t_k + dt]`` (exact displacement of the path over the step); zero at the end."""
        return self.path.step_twists(self.times(), self.dt)

    @cached_property
    def samples(self) -> PathSamples:
        """The sampled path (computed once per task)."""
        t = self.times()
        p_des, A_des = self.desired_pose(t)
        return PathSamples(
            t=np.ascontiguousarray(t, dtype=float),
            twists=np.ascontiguousarray(self.step_twists(), dtype=float),
            p_des=np.ascontiguousarray(p_des, dtype=float),
            A_des=np.ascontiguousarray(A_des, dtype=float),
            twist_des=self.desired_twist(t),
        )

    def to_summary(self) -> dict[str, object]:
        return {
            "n_steps": self.n_steps,
            "duration": self.duration,
            "dt": self.dt,
            "joint_speed_limit": self.joint_speed_limit,
            "linear_joint_speed_limit": self.linear_joint_speed_limit,
            "tracks": self.tracks,
            "path": self.path.summary(),
        }


def start_pose(model: RobotModel, q0: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """End-effector position (3,) m and attitude (3, 3) at ``q0`` (rad), base at the origin:
    where every path starts."""
    fk = forward_kinematics(model, as_state(model, q0))
    return fk.ee_position, fk.ee_attitude


def paper_task(model: RobotModel | None = None) -> CartesianTask:
    """The paper's detection line (docs/engine.md, "Conventions"): from FK at q0 = (175, -60, -60, 0,
    210, 5) deg to (1.50, 0, -0.20) m, SpaceDyn RPY (-3.16, -0.26, -3.14) rad; T = 15 s,
    ramp 1.5 s, dt = 0.25 s, trapezoidal profile, joint speed limit 6 deg/s."""
    model = model or table1_robot()
    return CartesianTask.from_q0(
        model,
        np.radians(PAPER_Q0_DEG),
        PAPER_TARGET_POSITION,
        rpy_spacedyn_to_matrix(PAPER_TARGET_RPY),
        duration=15.0,
        ramp_time=1.5,
        dt=0.25,
        profile="trapezoidal",
        joint_speed_limit=math.radians(6.0),
    )
