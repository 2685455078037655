"""Cartesian tasks: straight line in position, rotation about one fixed axis (paper eq. 2).

The path parameter ``s(t)`` runs from 0 to 1 with a trapezoidal (constant acceleration ramps)
or quintic (``10 tau^3 - 15 tau^4 + 6 tau^5``) profile and holds 1 after ``duration``:

- ``p_d(t) = p_start + s(t) (p_target - p_start)``
- ``A_d(t) = exp(s(t) [phi]x) A_start`` with ``exp([phi]x) = A_target A_start^T``
  (the axis ``r = phi / |phi|`` is fixed in world axes, angle ``|phi|``)
- desired twist ``[v_e; w_e] = sdot(t) [p_target - p_start; phi]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError, finite_array
from engine.kinematics import as_state, forward_kinematics
from engine.model import RobotModel, table1_robot
from engine.spatial import FloatArray, exp_so3, is_rotation, log_so3, rpy_spacedyn_to_matrix

Profile = Literal["trapezoidal", "quintic"]
PROFILES: tuple[str, ...] = ("trapezoidal", "quintic")
Tracks = Literal["pose", "position"]
TRACKS: dict[str, int] = {"pose": 6, "position": 3}  # what a task tracks -> rows of the GJM it needs
MAX_DURATION_S = 600.0
MAX_STEPS = 20_000

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
    """A point-to-point Cartesian task. SI units, rad; attitudes are rotation matrices
    (end effector -> world). The base starts at rest at the origin with identity attitude.

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
    tracks: Tracks = "pose"
    linear_joint_speed_limit: float = math.inf  # m/s, symmetric
    _phi: FloatArray = field(init=False, repr=False, compare=False)

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
        if not 0.0 < self.dt <= 1.0:
            raise ParameterError("dt", "must be in (0, 1] s")
        if not 0.0 <= self.ramp_time <= self.duration / 2.0:
            raise ParameterError("ramp_time", "must be in [0, duration / 2]")
        if self.profile not in PROFILES:
            raise ParameterError("profile", f"must be one of {', '.join(PROFILES)}")
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

    def path_parameter(self, times: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(s, sdot)`` of the profile at ``times`` (s); ``s`` in [0, 1]; the ramp time is
        ignored by the quintic profile."""
        t: FloatArray = np.clip(np.asarray(times, dtype=float), 0.0, self.duration)
        T, ta = self.duration, self.ramp_time
        if self.profile == "quintic":
            tau = t / T
            s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
            sdot = 30.0 * tau**2 * (1.0 - tau) ** 2 / T
            return s, sdot
        v = 1.0 / (T - ta)
        if ta == 0.0:
            return t * v, np.full_like(t, v)
        up = t < ta
        down = t > T - ta
        s = np.where(up, 0.5 * v * t**2 / ta, np.where(down, 1.0 - 0.5 * v * (T - t) ** 2 / ta, v * (t - 0.5 * ta)))
        sdot = np.where(up, v * t / ta, np.where(down, v * (T - t) / ta, v))
        return s, sdot

    def desired_pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(p_d (..., 3), A_d (..., 3, 3))`` at times ``t``."""
        s, _ = self.path_parameter(t)
        p = self.start_position + s[..., None] * (self.target_position - self.start_position)
        A = exp_so3(s[..., None] * self._phi) @ self.start_attitude
        return p, A

    def desired_twist(self, t: ArrayLike) -> FloatArray:
        """Instantaneous desired twist ``[v_e; w_e] (..., 6)`` (m/s, rad/s) at times ``t``."""
        _, sdot = self.path_parameter(t)
        direction = np.concatenate([self.target_position - self.start_position, self._phi])
        return sdot[..., None] * direction

    def step_twists(self) -> FloatArray:
        """Commanded twist per sample ``(n_steps + 1, 6)``: the mean desired twist over
        ``[t_k, t_k + dt]`` (exact displacement of the path over the step); zero at the end."""
        s, _ = self.path_parameter(self.times())
        direction = np.concatenate([self.target_position - self.start_position, self._phi])
        ds = np.append(np.diff(s), 0.0)
        return (ds / self.dt)[:, None] * direction

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
        }


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
