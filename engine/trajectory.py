"""Cartesian tasks: an initial configuration, a path to follow, a time step and a joint speed
limit; sampled once into what the planner's kernels consume (:class:`PathSamples`).

By default (``path=None``) the path is the paper's straight line (eq. 2) from the start pose to
the target pose, :class:`engine.paths.LinePath`: the path parameter ``s(t)`` runs from 0 to 1
with a trapezoidal (constant acceleration ramps) or quintic (``10 tau^3 - 15 tau^4 + 6 tau^5``)
profile and holds 1 after ``duration``:

- ``p_d(t) = p_start + s(t) (p_target - p_start)``
- ``A_d(t) = exp(s(t) [phi]x) A_start`` with ``exp([phi]x) = A_target A_start^T``
  (the axis ``r = phi / |phi|`` is fixed in world axes, angle ``|phi|``)
- desired twist ``[v_e; w_e] = sdot(t) [p_target - p_start; phi]``.

Any other :class:`engine.paths.Path` (waypoints, arc, raster) is given as ``path``
(:meth:`CartesianTask.following` or :meth:`CartesianTask.along`); the start and target fields
are then its end poses and ``duration`` its duration.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError, finite_array
from engine.kinematics import as_state, forward_kinematics
from engine.model import RobotModel, table1_robot
from engine.paths import PROFILES, LinePath, Path, Profile, make_path
from engine.spatial import FloatArray, is_rotation, log_so3, rotation_angle, rpy_spacedyn_to_matrix

__all__ = [
    "END_TOLERANCE",
    "MAX_DURATION_S",
    "MAX_STEPS",
    "MIN_DT_S",
    "PAPER_Q0_DEG",
    "PAPER_TARGET_POSITION",
    "PAPER_TARGET_RPY",
    "PROFILES",
    "TRACKS",
    "CartesianTask",
    "PathSamples",
    "Profile",
    "Tracks",
    "paper_task",
    "start_pose",
]

#: Poses at the ends of a given path must match the task's start and target to this (m, rad).
END_TOLERANCE = 1e-9

Tracks = Literal["pose", "position"]
TRACKS: dict[str, int] = {"pose": 6, "position": 3}  # what a task tracks -> rows of the GJM it needs
MAX_DURATION_S = 600.0
MAX_STEPS = 20_000
MIN_DT_S = 1e-4  # 0.1 ms: finer steps add rounding, not accuracy

#: The paper's initial joint angles (deg) and target pose (SpaceDyn RPY, rad).
PAPER_Q0_DEG = (175.0, -60.0, -60.0, 0.0, 210.0, 5.0)
PAPER_TARGET_POSITION = (1.50, 0.0, -0.20)
PAPER_TARGET_RPY = (-3.16, -0.26, -3.14)


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
    """A Cartesian task. SI units, rad; attitudes are rotation matrices (end effector -> world).
    The base starts at rest at the origin with identity attitude.

    Without ``path`` it is the point-to-point line from the start to the target pose in
    ``duration`` (``ramp_time`` and ``profile`` its time law). With ``path``, the start and
    target fields must be the path's end poses and ``duration`` its duration (use
    :meth:`following`); ``ramp_time`` and ``profile`` are then not used.

    ``tracks`` says what the planner follows: the whole ``"pose"`` (needs 6 joints or more) or
    the ``"position"`` only (3 or more; the attitude path is then reported, not tracked).
    ``joint_speed_limit`` (rad/s) applies to revolute joints, ``linear_joint_speed_limit``
    (m/s, unlimited by default) to prismatic ones."""

    q0: FloatArray  # (n,) rad
    start_position: FloatArray  # (3,) m
    start_attitude: FloatArray  # (3, 3)
    target_position: FloatArray  # (3,) m
    target_attitude: FloatArray  # (3, 3)
    duration: float = 15.0  # s
    ramp_time: float = 1.5  # s
    dt: float = 0.25  # s
    profile: Profile = "trapezoidal"
    joint_speed_limit: float = math.radians(6.0)  # rad/s, symmetric
    path: Path | None = None
    tracks: Tracks = "pose"
    linear_joint_speed_limit: float = math.inf  # m/s, symmetric
    _phi: FloatArray = field(init=False, repr=False, compare=False)
    _path: Path = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        q0 = np.array(self.q0, dtype=float).reshape(-1)
        if q0.size == 0 or not np.all(np.isfinite(q0)):
            raise ParameterError("q0", "expected finite joint angles")
        q0.setflags(write=False)
        object.__setattr__(self, "q0", q0)
        for name in ("start_position", "target_position"):
            object.__setattr__(self, name, finite_array(getattr(self, name), (3,), name))
        for name in ("start_attitude", "target_attitude"):
            att = finite_array(getattr(self, name), (3, 3), name)
            if not is_rotation(att):
                raise ParameterError(name, "must be a rotation matrix")
            object.__setattr__(self, name, att)
        for name in ("duration", "ramp_time", "dt", "joint_speed_limit"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ParameterError(name, "must be finite")
            object.__setattr__(self, name, value)
        if not 0.0 < self.duration <= MAX_DURATION_S:
            raise ParameterError("duration", f"must be in (0, {MAX_DURATION_S:g}] s")
        if not MIN_DT_S <= self.dt <= 1.0:
            raise ParameterError("dt", f"must be in [{MIN_DT_S:g}, 1] s")
        if self.path is None:
            path: Path = LinePath(
                self.start_position,
                self.start_attitude,
                self.target_position,
                self.target_attitude,
                self.duration,
                self.ramp_time,
                self.profile,
            )
        else:
            path = self.path
            self._check_path_ends(path)
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
        object.__setattr__(self, "_phi", log_so3(self.target_attitude @ self.start_attitude.T))
        object.__setattr__(self, "_path", path)

    def _check_path_ends(self, path: Path) -> None:
        if abs(path.duration - self.duration) > END_TOLERANCE * max(1.0, self.duration):
            raise ParameterError("duration", f"must be the path's duration ({path.duration:g} s); see with_duration")
        ends = path.pose(np.array([0.0, path.duration]))
        for i, (position, attitude) in enumerate((("start_position", "start_attitude"), ("target_position", "target_attitude"))):
            if np.linalg.norm(ends[0][i] - getattr(self, position)) > END_TOLERANCE:
                raise ParameterError(position, "must be the path's end position")
            if rotation_angle(ends[1][i] @ getattr(self, attitude).T) > END_TOLERANCE:
                raise ParameterError(attitude, "must be the path's end attitude")

    @classmethod
    def from_q0(
        cls,
        model: RobotModel,
        q0: ArrayLike,
        target_position: ArrayLike,
        target_attitude: ArrayLike,
        **options: object,
    ) -> CartesianTask:
        """Task starting from the forward kinematics at ``q0`` (base at the origin)."""
        state = as_state(model, q0)
        fk = forward_kinematics(model, state)
        return cls(
            q0=state.q,
            start_position=fk.ee_position,
            start_attitude=fk.ee_attitude,
            target_position=np.asarray(target_position, dtype=float),
            target_attitude=np.asarray(target_attitude, dtype=float),
            **options,  # type: ignore[arg-type]
        )

    @classmethod
    def following(cls, path: Path, q0: ArrayLike, **options: Any) -> CartesianTask:
        """The task that follows ``path`` from ``q0`` (rad; the path must start at the
        end-effector pose of ``q0``); ``options``: ``dt``, ``joint_speed_limit``."""
        p, A = path.pose(np.array([0.0, path.duration]))
        return cls(
            q0=np.asarray(q0, dtype=float),
            start_position=p[0],
            start_attitude=A[0],
            target_position=p[1],
            target_attitude=A[1],
            duration=path.duration,
            ramp_time=0.0,
            path=path,
            **options,
        )

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
        origin). A ``line`` is the classic task (``target_position``, ``target_attitude``,
        ``duration``, ``ramp_time``, ``profile``)."""
        options: dict[str, Any] = {"dt": dt, "joint_speed_limit": joint_speed_limit}
        if kind == "line":
            target_position, target_attitude = spec.pop("target_position"), spec.pop("target_attitude")
            return cls.from_q0(model, q0, target_position, target_attitude, **options, **spec)
        position, attitude = start_pose(model, q0)
        return cls.following(make_path(kind, position, attitude, **spec), q0, **options)

    def with_duration(self, duration: float) -> CartesianTask:
        """The same task with its path retimed to ``duration`` s (every speed scaled; a line's
        ramp time scales with it)."""
        path = self._path.retimed(duration)
        if self.path is None:  # the task's own line: its fields are the line's
            assert isinstance(path, LinePath)
            return dataclasses.replace(self, duration=path.duration, ramp_time=path.ramp_time)
        return dataclasses.replace(self, path=path, duration=path.duration)

    @property
    def n_steps(self) -> int:
        """Number of integration steps; the last sample is at ``n_steps * dt >= duration``."""
        return max(1, math.ceil(self.duration / self.dt - 1e-9))

    @property
    def rotation_vector(self) -> FloatArray:
        """``phi (3,)``: axis times angle (rad) of the rotation from start to target, world axes."""
        return self._phi

    def times(self) -> FloatArray:
        """Sample times ``(n_steps + 1,)`` s."""
        return np.arange(self.n_steps + 1) * self.dt

    @property
    def followed(self) -> Path:
        """The path the task follows (its line when no path was given)."""
        return self._path

    @property
    def kind(self) -> str:
        """The path type: ``line``, ``waypoints``, ``arc`` or ``raster``."""
        return self._path.kind

    def path_parameter(self, times: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(s, sdot)`` of a line's profile at ``times`` (s); ``s`` in [0, 1]; the ramp time is
        ignored by the quintic profile."""
        if not isinstance(self._path, LinePath):
            raise ParameterError("path", f"a {self.kind} path has no single path parameter")
        return self._path.path_parameter(times)

    def desired_pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(p_d (..., 3), A_d (..., 3, 3))`` at times ``t``."""
        return self._path.pose(t)

    def desired_twist(self, t: ArrayLike) -> FloatArray:
        """Instantaneous desired twist ``[v_e; w_e] (..., 6)`` (m/s, rad/s) at times ``t``."""
        return self._path.twist(t)

    def step_twists(self) -> FloatArray:
        """Commanded twist per sample ``(n_steps + 1, 6)``: the mean desired twist over
        ``[t_k, t_k + dt]`` (exact displacement of the path over the step); zero at the end."""
        return self._path.step_twists(self.times(), self.dt)

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
            "ramp_time": self.ramp_time,
            "dt": self.dt,
            "profile": self.profile,
            "joint_speed_limit": self.joint_speed_limit,
            "linear_joint_speed_limit": self.linear_joint_speed_limit,
            "tracks": self.tracks,
            "rotation_angle": float(np.linalg.norm(self._phi)),
            "path": self._path.summary(),
        }


def start_pose(model: RobotModel, q0: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """End-effector position (3,) m and attitude (3, 3) at ``q0`` (rad), base at the origin:
    where every path starts."""
    fk = forward_kinematics(model, as_state(model, q0))
    return fk.ee_position, fk.ee_attitude


def paper_task(model: RobotModel | None = None) -> CartesianTask:
    """The paper's detection line (``robot-table1.md``): from FK at q0 = (175, -60, -60, 0,
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
