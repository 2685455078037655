"""Path strategies: time-parameterised end-effector pose trajectories (what a task follows).

A path gives, for ``t`` in ``[0, duration]`` s (and held after), the desired pose ``p_d(t) (3,)``
m and ``A_d(t) (3, 3)`` (end effector -> world), the instantaneous desired twist
``[v; w] (6,)`` (m/s, rad/s, world axes, ``dA_d/dt = [w]x A_d``) and, at the planner's sample
times, the per-step displacement twists the kernels consume: ``v_k = (p_{k+1} - p_k) / dt`` and
``w_k = log(A_{k+1} A_k^T) / dt`` (world axes), zero at the last sample, so that
``p_k + v_k dt = p_{k+1}`` and ``exp([w_k dt]x) A_k = A_{k+1}`` exactly (to rounding).

Every path starts at the end-effector pose of the task's initial configuration. The types,
chosen by name only at the boundary (:func:`make_path`):

- :class:`LinePath` (``line``): straight line to a target pose, the attitude rotating about one
  fixed world axis, on a trapezoidal or quintic time law (the paper's task).
- :class:`WaypointPath` (``waypoints``): poses visited in order, each segment a straight line
  and an SO(3) geodesic on one quintic law (rest to rest). Quintic segments rather than corner
  blends: the end effector passes *through* every pose (an inspection pose is a place to look,
  a blend would cut it), velocity and acceleration are continuous (zero at each waypoint), and
  position and attitude share one law, so the attitude stays on the geodesic. Timed by maximum
  linear and angular speeds and accelerations (the slowest limit sets each segment's duration)
  or by given per-segment durations.
- :class:`ArcPath` (``arc``): a circular arc about an axis through a centre (or through a via
  point to an end point), the attitude turning with the arc's tangent frame or held fixed.
- :class:`RasterPath` (``raster``): a boustrophedon scan of a rectangular patch at a stand-off
  distance along its normal, the sensor axis (an axis of the end-effector frame) pointing at the
  patch; passes joined by circular turns, the whole scan at one speed with acceleration ramps at
  its ends, after a quintic approach from the start pose.

Every path can be retimed uniformly (:meth:`Path.retimed`): the same geometry with every speed
scaled, which is what the shortest-duration search varies.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Protocol, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError, finite_array
from engine.spatial import FloatArray, cross, exp_so3, is_rotation, log_so3, rotation_angle

Profile = Literal["trapezoidal", "quintic"]
PROFILES: tuple[str, ...] = ("trapezoidal", "quintic")
ARC_ATTITUDES: tuple[str, ...] = ("tangent", "fixed")
MAX_WAYPOINTS = 100
MAX_PASSES = 200
#: Segments shorter than this in both position (m) and rotation (rad) are zero-length.
MIN_SEGMENT = 1e-6
#: ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``: peak ``ds/dtau`` and ``d2s/dtau2``.
QUINTIC_PEAK_SPEED = 15.0 / 8.0
QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)


class Path(Protocol):
    """A time-parameterised pose trajectory (see the module docstring)."""

    kind: ClassVar[str]

    @property
    def duration(self) -> float:
        """s; the pose is held after it."""
        ...

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """``(p_d (..., 3), A_d (..., 3, 3))`` at times ``t (...)`` s."""
        ...

    def twist(self, t: ArrayLike) -> FloatArray:
        """Instantaneous desired twist ``[v; w] (..., 6)`` (m/s, rad/s, world axes)."""
        ...

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        """Displacement twist per sample ``(N+1, 6)`` for ``times = k dt``; zero at the end."""
        ...

    def retimed(self, duration: float) -> Path:
        """The same geometry traversed in ``duration`` s (every speed scaled uniformly)."""
        ...

    def summary(self) -> dict[str, Any]:
        """Type, duration and the main geometric figures (SI units)."""
        ...


# --- shared pieces ----------------------------------------------------------------------------


def _flat(t: ArrayLike) -> tuple[FloatArray, tuple[int, ...]]:
    arr = np.asarray(t, dtype=float)
    return arr.reshape(-1), arr.shape


def quintic(t: FloatArray, T: FloatArray | float) -> tuple[FloatArray, FloatArray]:
    """``(s, sdot)`` of ``s = 10 tau^3 - 15 tau^4 + 6 tau^5``, ``tau = t / T`` (``t`` in [0, T])."""
    tau = t / T
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    sdot = 30.0 * tau**2 * (1.0 - tau) ** 2 / T
    return s, sdot


def time_law(times: ArrayLike, duration: float, ramp_time: float, profile: str) -> tuple[FloatArray, FloatArray]:
    """``(s, sdot)`` at ``times`` (s) of a path parameter running from 0 to 1 in ``duration``:
    trapezoidal (constant-acceleration ramps of ``ramp_time``) or quintic (the ramp time is
    ignored); ``s`` holds 1 after ``duration``."""
    t: FloatArray = np.clip(np.asarray(times, dtype=float), 0.0, duration)
    T, ta = duration, ramp_time
    if profile == "quintic":
        return quintic(t, T)
    v = 1.0 / (T - ta)
    if ta == 0.0:
        return t * v, np.full_like(t, v)
    up = t < ta
    down = t > T - ta
    s = np.where(up, 0.5 * v * t**2 / ta, np.where(down, 1.0 - 0.5 * v * (T - t) ** 2 / ta, v * (t - 0.5 * ta)))
    sdot = np.where(up, v * t / ta, np.where(down, v * (T - t) / ta, v))
    return s, sdot


def check_timing(duration: float, ramp_time: float, profile: str) -> None:
    """The checks of a single time law (field names ``duration``, ``ramp_time``, ``profile``)."""
    if not (math.isfinite(duration) and duration > 0.0):
        raise ParameterError("duration", "must be finite and > 0")
    if not (math.isfinite(ramp_time) and 0.0 <= ramp_time <= duration / 2.0):
        raise ParameterError("ramp_time", "must be in [0, duration / 2]")
    if profile not in PROFILES:
        raise ParameterError("profile", f"must be one of {', '.join(PROFILES)}")


def geodesic(p_a: FloatArray, A_a: FloatArray, dp: FloatArray, phi: FloatArray, s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Poses at parameters ``s (...)`` of the straight line ``p_a + s dp`` and the SO(3)
    geodesic ``exp(s [phi]x) A_a`` (``phi`` in world axes); inputs broadcast over ``...``."""
    p = p_a + s[..., None] * dp
    A = exp_so3(s[..., None] * phi) @ A_a
    return p, A


def displacement_twists(p: FloatArray, A: FloatArray, dt: float) -> FloatArray:
    """Per-step twists ``(N+1, 6)`` of sampled poses ``p (N+1, 3)``, ``A (N+1, 3, 3)``:
    ``[(p_{k+1} - p_k) / dt; log(A_{k+1} A_k^T) / dt]``, zero at the last sample."""
    out = np.zeros((p.shape[0], 6))
    out[:-1, :3] = np.diff(p, axis=0) / dt
    out[:-1, 3:] = log_so3(A[1:] @ np.swapaxes(A[:-1], -1, -2)) / dt
    return out


def _position(value: ArrayLike, name: str) -> FloatArray:
    return finite_array(value, (3,), name)


def _attitude(value: ArrayLike, name: str) -> FloatArray:
    arr = finite_array(value, (3, 3), name)
    if not is_rotation(arr):
        raise ParameterError(name, "must be a rotation matrix")
    return arr


def _direction(value: ArrayLike, name: str) -> FloatArray:
    arr = np.array(finite_array(value, (3,), name))
    norm = float(np.linalg.norm(arr))
    if norm < 1e-12:
        raise ParameterError(name, "must be a non-zero vector")
    unit = arr / norm
    unit.setflags(write=False)
    return unit


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(name, "must be finite and > 0")
    return value


def _scale(duration: float | None, natural: float) -> float:
    """The time scale of an optional duration override (``duration / natural``)."""
    if duration is None:
        return 1.0
    return _positive(duration, "duration") / natural


_Law = TypeVar("_Law", "LinePath", "ArcPath")


def _retimed_law(path: _Law, duration: float) -> _Law:
    """A path on one :func:`time_law` retimed to ``duration``: its ramp scales with it."""
    duration = _positive(duration, "duration")
    ramp = min(path.ramp_time * (duration / path.duration), duration / 2.0)
    return dataclasses.replace(path, duration=duration, ramp_time=ramp)


def _law_summary(path: LinePath | ArcPath) -> dict[str, Any]:
    """The summary entries of a path on one :func:`time_law`."""
    return {"type": path.kind, "duration": path.duration, "ramp_time": path.ramp_time, "profile": path.profile}


@dataclass(frozen=True)
class SpeedLimits:
    """Cartesian limits that time rest-to-rest moves: linear (m/s, m/s^2) and angular (rad/s,
    rad/s^2) speed and acceleration."""

    speed: float = 0.05
    angular_speed: float = math.radians(5.0)
    acceleration: float = 0.02
    angular_acceleration: float = math.radians(2.0)

    def __post_init__(self) -> None:
        for name in ("speed", "angular_speed", "acceleration", "angular_acceleration"):
            object.__setattr__(self, name, _positive(getattr(self, name), f"max_{name}"))

    def move_duration(self, length: float, angle: float) -> float:
        """Duration (s) of a quintic move of ``length`` m and ``angle`` rad within the limits."""
        return max(
            QUINTIC_PEAK_SPEED * length / self.speed,
            math.sqrt(QUINTIC_PEAK_ACCELERATION * length / self.acceleration),
            QUINTIC_PEAK_SPEED * angle / self.angular_speed,
            math.sqrt(QUINTIC_PEAK_ACCELERATION * angle / self.angular_acceleration),
        )


@dataclass(frozen=True)
class _Segments:
    """Rest-to-rest moves between knot poses ``p (M+1, 3)``, ``A (M+1, 3, 3)``: straight line and
    geodesic on one quintic law each, of ``durations (M,)`` s, one after the other."""

    p: FloatArray
    A: FloatArray
    durations: FloatArray
    starts: FloatArray = field(init=False, repr=False)
    dp: FloatArray = field(init=False, repr=False)
    phi: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "starts", np.concatenate([[0.0], np.cumsum(self.durations)[:-1]]))
        object.__setattr__(self, "dp", np.diff(self.p, axis=0))
        object.__setattr__(self, "phi", log_so3(self.A[1:] @ np.swapaxes(self.A[:-1], -1, -2)))

    @property
    def duration(self) -> float:
        return float(np.sum(self.durations))

    def scaled(self, factor: float) -> _Segments:
        return _Segments(self.p, self.A, self.durations * factor)

    def _law(self, t: FloatArray) -> tuple[np.ndarray, FloatArray, FloatArray]:
        t = np.clip(t, 0.0, self.duration)
        k = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, self.durations.shape[0] - 1)
        local = np.clip(t - self.starts[k], 0.0, self.durations[k])
        s, sdot = quintic(local, self.durations[k])
        return k, s, sdot

    def pose(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        k, s, _ = self._law(t)
        return geodesic(self.p[k], self.A[k], self.dp[k], self.phi[k], s)

    def twist(self, t: FloatArray) -> FloatArray:
        k, _, sdot = self._law(t)
        out: FloatArray = sdot[:, None] * np.concatenate([self.dp[k], self.phi[k]], axis=1)
        return out


# --- line -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinePath:
    """Straight line from the start pose to the target pose; the attitude rotates about the fixed
    world axis of ``phi = log(A_target A_start^T)`` (paper eq. 2):
    ``p_d = p_start + s (p_target - p_start)``, ``A_d = exp(s [phi]x) A_start``,
    ``[v; w] = sdot [p_target - p_start; phi]``, with ``s(t)`` of :func:`time_law`."""

    kind: ClassVar[str] = "line"
    start_position: FloatArray
    start_attitude: FloatArray
    target_position: FloatArray
    target_attitude: FloatArray
    duration: float = 15.0
    ramp_time: float = 1.5
    profile: str = "trapezoidal"
    _phi: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("start_position", "target_position"):
            object.__setattr__(self, name, _position(getattr(self, name), name))
        for name in ("start_attitude", "target_attitude"):
            object.__setattr__(self, name, _attitude(getattr(self, name), name))
        object.__setattr__(self, "duration", float(self.duration))
        object.__setattr__(self, "ramp_time", float(self.ramp_time))
        check_timing(self.duration, self.ramp_time, self.profile)
        object.__setattr__(self, "_phi", log_so3(self.target_attitude @ self.start_attitude.T))

    @property
    def rotation_vector(self) -> FloatArray:
        return self._phi

    @property
    def _direction(self) -> FloatArray:
        return np.concatenate([self.target_position - self.start_position, self._phi])

    def path_parameter(self, times: ArrayLike) -> tuple[FloatArray, FloatArray]:
        return time_law(times, self.duration, self.ramp_time, self.profile)

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        s, _ = self.path_parameter(t)
        return geodesic(self.start_position, self.start_attitude, self.target_position - self.start_position, self._phi, s)

    def twist(self, t: ArrayLike) -> FloatArray:
        _, sdot = self.path_parameter(t)
        out: FloatArray = sdot[..., None] * self._direction
        return out

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        """``(s_{k+1} - s_k) / dt`` times the line's direction: the exact displacement (the
        rotation about one fixed axis composes additively)."""
        s, _ = self.path_parameter(times)
        ds = np.append(np.diff(s), 0.0)
        out: FloatArray = (ds / dt)[:, None] * self._direction
        return out

    def retimed(self, duration: float) -> LinePath:
        return _retimed_law(self, duration)

    def summary(self) -> dict[str, Any]:
        return {
            **_law_summary(self),
            "length": float(np.linalg.norm(self.target_position - self.start_position)),
            "rotation_angle": float(np.linalg.norm(self._phi)),
        }


# --- waypoints --------------------------------------------------------------------------------


@dataclass(frozen=True)
class WaypointPath:
    """The start pose, then ``positions (W, 3)`` m with ``attitudes (W, 3, 3)`` in order, each
    segment rest to rest on a quintic law (see the module docstring). Segment durations are
    ``segment_durations (W,)`` s if given, else the shortest within ``limits``; ``duration``, if
    given, rescales them uniformly to that total."""

    kind: ClassVar[str] = "waypoints"
    start_position: FloatArray
    start_attitude: FloatArray
    positions: FloatArray
    attitudes: FloatArray
    limits: SpeedLimits = field(default_factory=SpeedLimits)
    segment_durations: FloatArray | None = None
    duration_override: float | None = None
    _segments: _Segments = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        start_p = _position(self.start_position, "start_position")
        start_A = _attitude(self.start_attitude, "start_attitude")
        positions = np.asarray(self.positions, dtype=float)
        attitudes = np.asarray(self.attitudes, dtype=float)
        count = positions.shape[0] if positions.ndim == 2 else 0
        if not 1 <= count <= MAX_WAYPOINTS:
            raise ParameterError("waypoints", f"expected 1 to {MAX_WAYPOINTS} waypoints")
        if attitudes.shape != (count, 3, 3):
            raise ParameterError("waypoints", "expected one attitude per waypoint")
        for i in range(count):
            _position(positions[i], f"waypoints[{i}].position")
            _attitude(attitudes[i], f"waypoints[{i}].attitude")
        p = np.concatenate([start_p[None], positions])
        A = np.concatenate([start_A[None], attitudes])
        lengths = np.linalg.norm(np.diff(p, axis=0), axis=1)
        angles = rotation_angle(A[1:] @ np.swapaxes(A[:-1], -1, -2))
        for i in range(count):
            if lengths[i] < MIN_SEGMENT and angles[i] < MIN_SEGMENT:
                before = "the start pose" if i == 0 else f"waypoint {i - 1}"
                raise ParameterError(f"waypoints[{i}]", f"zero-length segment: the same pose as {before}")
        if self.segment_durations is not None:
            durations = np.asarray(self.segment_durations, dtype=float).reshape(-1)
            if durations.shape != (count,):
                raise ParameterError("segment_durations", f"expected {count} durations, one per waypoint")
            for i, d in enumerate(durations):
                _positive(d, f"segment_durations[{i}]")
        else:
            durations = np.array([self.limits.move_duration(float(L), float(a)) for L, a in zip(lengths, angles, strict=True)])
        durations = durations * _scale(self.duration_override, float(np.sum(durations)))
        object.__setattr__(self, "_segments", _Segments(p, A, durations))

    @property
    def duration(self) -> float:
        return self._segments.duration

    @property
    def segment_times(self) -> FloatArray:
        """Arrival time (s) at each waypoint ``(W,)``."""
        return np.cumsum(self._segments.durations)

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        flat, shape = _flat(t)
        p, A = self._segments.pose(flat)
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = _flat(t)
        return self._segments.twist(flat).reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> WaypointPath:
        return dataclasses.replace(self, duration_override=_positive(duration, "duration"))

    def summary(self) -> dict[str, Any]:
        return {
            "type": self.kind,
            "duration": self.duration,
            "waypoints": int(self.positions.shape[0]),
            "segment_durations": self._segments.durations.tolist(),
            "length": float(np.sum(np.linalg.norm(self._segments.dp, axis=1))),
            "rotation_angle": float(np.sum(np.linalg.norm(self._segments.phi, axis=1))),
        }


# --- arc --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ArcPath:
    """A circular arc: the start position turned by ``angle`` rad (right hand about ``axis``)
    about the line through ``centre`` along ``axis``, on a :func:`time_law`:
    ``p_d = c + R(s) (p_start - c)`` with ``R(s) = exp(s angle [axis]x)``; the attitude
    ``R(s) A_start`` (``"tangent"``: it keeps its attitude relative to the arc's tangent frame)
    or ``A_start`` (``"fixed"``)."""

    kind: ClassVar[str] = "arc"
    start_position: FloatArray
    start_attitude: FloatArray
    centre: FloatArray
    axis: FloatArray
    angle: float
    attitude: str = "tangent"
    duration: float = 15.0
    ramp_time: float = 1.5
    profile: str = "trapezoidal"

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_position", _position(self.start_position, "start_position"))
        object.__setattr__(self, "start_attitude", _attitude(self.start_attitude, "start_attitude"))
        object.__setattr__(self, "centre", _position(self.centre, "centre"))
        object.__setattr__(self, "axis", _direction(self.axis, "axis"))
        angle = float(self.angle)
        if not (math.isfinite(angle) and 1e-9 < abs(angle) <= 2.0 * math.pi):
            raise ParameterError("angle", "must be non-zero and at most one turn (360 deg) in magnitude")
        object.__setattr__(self, "angle", angle)
        if self.attitude not in ARC_ATTITUDES:
            raise ParameterError("attitude", f"must be one of {', '.join(ARC_ATTITUDES)}")
        if self.radius < MIN_SEGMENT:
            raise ParameterError("centre", "the start position lies on the arc's axis (zero radius)")
        object.__setattr__(self, "duration", float(self.duration))
        object.__setattr__(self, "ramp_time", float(self.ramp_time))
        check_timing(self.duration, self.ramp_time, self.profile)

    @classmethod
    def through(
        cls, start_position: ArrayLike, start_attitude: ArrayLike, via: ArrayLike, end: ArrayLike, **options: Any
    ) -> ArcPath:
        """The arc from the start position through ``via`` to ``end`` (three points of a circle)."""
        p1 = _position(start_position, "start_position")
        p2 = _position(via, "via_position")
        p3 = _position(end, "end_position")
        a, b = p1 - p3, p2 - p3
        n = np.cross(p2 - p1, p3 - p2)
        scale = max(float(np.linalg.norm(p2 - p1) * np.linalg.norm(p3 - p2)), 1e-300)
        if float(np.linalg.norm(p2 - p1)) < MIN_SEGMENT or float(np.linalg.norm(p3 - p2)) < MIN_SEGMENT:
            raise ParameterError("via_position", "the three points of the arc must be distinct")
        if float(np.linalg.norm(n)) < 1e-9 * scale or float(np.linalg.norm(a)) < MIN_SEGMENT:
            raise ParameterError("via_position", "start, via and end positions are collinear or end at the start: no arc")
        axb = np.cross(a, b)
        centre = p3 + np.cross(a.dot(a) * b - b.dot(b) * a, axb) / (2.0 * axb.dot(axb))
        axis = n / np.linalg.norm(n)
        r1, r3 = p1 - centre, p3 - centre
        angle = math.atan2(float(axis.dot(np.cross(r1, r3))), float(r1.dot(r3)))
        if angle <= 0.0:
            angle += 2.0 * math.pi
        return cls(p1, start_attitude, centre, axis, angle, **options)  # type: ignore[arg-type]

    @property
    def radius(self) -> float:
        r = self.start_position - self.centre
        return float(np.linalg.norm(r - r.dot(self.axis) * self.axis))

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        flat, shape = _flat(t)
        s, _ = time_law(flat, self.duration, self.ramp_time, self.profile)
        R = exp_so3((s * self.angle)[:, None] * self.axis)
        p = self.centre + R @ (self.start_position - self.centre)
        A = R @ self.start_attitude if self.attitude == "tangent" else np.broadcast_to(self.start_attitude, R.shape).copy()
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = _flat(t)
        _, sdot = time_law(flat, self.duration, self.ramp_time, self.profile)
        w = (sdot * self.angle)[:, None] * self.axis
        p, _ = self.pose(flat)
        v = cross(w, p - self.centre)
        out = np.concatenate([v, w if self.attitude == "tangent" else np.zeros_like(w)], axis=1)
        return out.reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> ArcPath:
        return _retimed_law(self, duration)

    def summary(self) -> dict[str, Any]:
        return {
            **_law_summary(self),
            "radius": self.radius,
            "angle": self.angle,
            "length": self.radius * abs(self.angle),
            "attitude": self.attitude,
        }


# --- raster -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Curve:
    """A tangent-continuous plane curve of straight and circular pieces at one attitude, on a
    trapezoidal speed law over its length ``L``: ``sigma(t) = L s(t)``.

    Piece ``i`` starts at ``start[i]`` (arc length ``offset[i]``, length ``length[i]``); a straight
    piece runs along the unit ``tangent[i]``; an arc (``radius[i] > 0``) turns the radius vector
    ``start[i] - centre[i]`` about the unit ``normal[i]`` (right hand) by ``length / radius``.
    """

    start: FloatArray  # (P, 3)
    tangent: FloatArray  # (P, 3)
    centre: FloatArray  # (P, 3)
    normal: FloatArray  # (P, 3)
    radius: FloatArray  # (P,), 0 for straight pieces
    length: FloatArray  # (P,)
    attitude: FloatArray  # (3, 3)
    duration: float
    ramp_time: float
    offset: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "offset", np.concatenate([[0.0], np.cumsum(self.length)[:-1]]))

    @classmethod
    def build(cls, pieces: Sequence[tuple[Any, ...]], attitude: FloatArray, speed: float, acceleration: float) -> _Curve:
        """From pieces ``("line", a, b)`` and ``("arc", centre, normal, start, angle)``, timed by
        a trapezoidal law of peak ``speed`` and ``acceleration`` (a triangle when too short)."""
        rows = []
        for piece in pieces:
            if piece[0] == "line":
                a, b = piece[1], piece[2]
                size = float(np.linalg.norm(b - a))
                rows.append((a, (b - a) / size, a, np.zeros(3), 0.0, size))
            else:
                centre, normal, start, angle = piece[1:]
                r = float(np.linalg.norm(start - centre))
                rows.append((start, np.cross(normal, start - centre) / r, centre, normal, r, r * angle))
        columns = [np.array(c, dtype=float) for c in zip(*rows, strict=True)]
        total = float(np.sum(columns[5]))
        ramp = speed / acceleration
        if total >= speed * ramp:
            duration = total / speed + ramp
        else:  # never reaches the speed: accelerate half way, then brake
            ramp = math.sqrt(total / acceleration)
            duration = 2.0 * ramp
        start, tangent, centre, normal, radius, lengths = columns
        return cls(start, tangent, centre, normal, radius, lengths, attitude, duration, ramp)

    @property
    def total_length(self) -> float:
        return float(np.sum(self.length))

    def scaled(self, factor: float) -> _Curve:
        return dataclasses.replace(self, duration=self.duration * factor, ramp_time=self.ramp_time * factor)

    def _locate(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, unit tangent and path speed (m/s) at times ``t (N,)``."""
        s, sdot = time_law(t, self.duration, self.ramp_time, "trapezoidal")
        L = self.total_length
        sigma = np.clip(s * L, 0.0, L)
        k = np.clip(np.searchsorted(self.offset, sigma, side="right") - 1, 0, self.length.shape[0] - 1)
        lam = np.clip(sigma - self.offset[k], 0.0, self.length[k])
        arc = self.radius[k] > 0.0
        r = np.where(arc, self.radius[k], 1.0)
        theta = np.where(arc, lam / r, 0.0)[:, None]
        r0 = self.start[k] - self.centre[k]
        side = cross(self.normal[k], r0)
        on_arc = self.centre[k] + r0 * np.cos(theta) + side * np.sin(theta)
        on_line = self.start[k] + lam[:, None] * self.tangent[k]
        p = np.where(arc[:, None], on_arc, on_line)
        arc_tangent = (side * np.cos(theta) - r0 * np.sin(theta)) / r[:, None]
        tangent = np.where(arc[:, None], arc_tangent, self.tangent[k])
        return p, tangent, sdot * L

    def pose(self, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        p, _, _ = self._locate(t)
        return p, np.broadcast_to(self.attitude, (t.shape[0], 3, 3)).copy()

    def twist(self, t: FloatArray) -> FloatArray:
        _, tangent, speed = self._locate(t)
        return np.concatenate([speed[:, None] * tangent, np.zeros((t.shape[0], 3))], axis=1)


def minimal_rotation(a: FloatArray, b: FloatArray) -> FloatArray:
    """The smallest rotation ``R (3, 3)`` with ``R a = b`` for unit vectors ``a``, ``b``."""
    c = np.cross(a, b)
    sin, cos = float(np.linalg.norm(c)), float(a.dot(b))
    if sin > 1e-12:
        return exp_so3(c / sin * math.atan2(sin, cos))
    if cos > 0.0:
        return np.eye(3)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    axis = np.cross(a, helper)
    return exp_so3(axis / np.linalg.norm(axis) * math.pi)


@dataclass(frozen=True)
class RasterPath:
    """A boustrophedon scan of the rectangle ``corner + x scan_edge + y step_edge`` (x, y in
    [0, 1]) from its side along the normal ``n = scan_edge x step_edge / |...|``.

    The end effector stays at ``standoff`` m along ``n`` with the sensor axis (``sensor_axis``,
    a unit vector of the end-effector frame) pointing at the patch (``A_d sensor_axis = -n``):
    the scan attitude is the smallest rotation of the start attitude that does so. Passes run
    along ``scan_edge`` at ``y = i line_spacing / |step_edge|`` (i = 0, 1, ... while within the
    patch), alternating direction, joined outside the patch by circular turns of
    ``turn_radius`` (quarter circles and a straight piece, or a half circle when the radius is
    half the spacing). The scan runs at ``scan_speed`` m/s with ramps of ``scan_acceleration``
    m/s^2 at its two ends, after a quintic approach (``approach`` limits) from the start pose to
    the first pass. ``pass_index`` scans that pass only (for tuning over the passes of a scan);
    ``duration_override`` rescales the whole path uniformly.
    """

    kind: ClassVar[str] = "raster"
    start_position: FloatArray
    start_attitude: FloatArray
    corner: FloatArray
    scan_edge: FloatArray
    step_edge: FloatArray
    line_spacing: float
    standoff: float
    scan_speed: float
    scan_acceleration: float = 0.01
    turn_radius: float | None = None
    sensor_axis: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    approach: SpeedLimits = field(default_factory=SpeedLimits)
    pass_index: int | None = None
    duration_override: float | None = None
    _approach: _Segments | None = field(init=False, repr=False, compare=False)
    _scan: _Curve = field(init=False, repr=False, compare=False)
    _lines: tuple[tuple[FloatArray, FloatArray], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        start_p = _position(self.start_position, "start_position")
        start_A = _attitude(self.start_attitude, "start_attitude")
        corner = _position(self.corner, "corner")
        u = _position(self.scan_edge, "scan_edge")
        v = _position(self.step_edge, "step_edge")
        if float(np.linalg.norm(u)) < MIN_SEGMENT:
            raise ParameterError("scan_edge", "must be a non-zero vector")
        if float(np.linalg.norm(v)) < MIN_SEGMENT:
            raise ParameterError("step_edge", "must be a non-zero vector")
        width = float(np.linalg.norm(v))
        if abs(float(u.dot(v))) > 1e-6 * float(np.linalg.norm(u)) * width:
            raise ParameterError("step_edge", "must be perpendicular to scan_edge (a rectangular patch)")
        spacing = _positive(self.line_spacing, "line_spacing")
        if spacing > width * (1.0 + 1e-12):
            raise ParameterError("line_spacing", f"{spacing:g} m is wider than the patch ({width:g} m): no second pass")
        passes = math.floor(width / spacing + 1e-9) + 1
        if passes > MAX_PASSES:
            raise ParameterError("line_spacing", f"gives {passes} passes, at most {MAX_PASSES} allowed")
        standoff = _positive(self.standoff, "standoff")
        speed = _positive(self.scan_speed, "scan_speed")
        acceleration = _positive(self.scan_acceleration, "scan_acceleration")
        radius = spacing / 2.0 if self.turn_radius is None else _positive(self.turn_radius, "turn_radius")
        if radius > spacing / 2.0 * (1.0 + 1e-12):
            raise ParameterError("turn_radius", f"must be at most half the line spacing ({spacing / 2.0:g} m)")
        axis = _direction(self.sensor_axis, "sensor_axis")
        if self.pass_index is not None and not 0 <= int(self.pass_index) < passes:
            raise ParameterError("pass_index", f"must be in [0, {passes - 1}] ({passes} passes)")
        for name, value in (("line_spacing", spacing), ("standoff", standoff), ("turn_radius", radius)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "scan_speed", speed)
        object.__setattr__(self, "scan_acceleration", acceleration)
        object.__setattr__(self, "sensor_axis", axis)

        n = np.cross(u, v)
        n /= np.linalg.norm(n)
        u_hat, v_hat = u / np.linalg.norm(u), v / width
        lines = []
        for i in range(passes):
            a = corner + standoff * n + i * spacing * v_hat
            b = a + u
            lines.append((a, b) if i % 2 == 0 else (b, a))
        object.__setattr__(self, "_lines", tuple(lines))
        chosen = range(passes) if self.pass_index is None else [int(self.pass_index)]
        pieces: list[tuple[Any, ...]] = []
        for i in chosen:
            a, b = lines[i]
            pieces.append(("line", a, b))
            if self.pass_index is None and i + 1 < passes:
                pieces.extend(_turn(b, lines[i + 1][0], u_hat if i % 2 == 0 else -u_hat, v_hat, n, radius))
        attitude = minimal_rotation(start_A @ axis, -n) @ start_A
        scan = _Curve.build(pieces, attitude, speed, acceleration)
        entry = pieces[0][1]
        reach, turn = float(np.linalg.norm(entry - start_p)), float(rotation_angle(attitude @ start_A.T))
        approach = None
        if reach >= MIN_SEGMENT or turn >= MIN_SEGMENT:
            knots_p, knots_A = np.stack([start_p, entry]), np.stack([start_A, attitude])
            approach = _Segments(knots_p, knots_A, np.array([self.approach.move_duration(reach, turn)]))
        natural = scan.duration + (approach.duration if approach is not None else 0.0)
        factor = _scale(self.duration_override, natural)
        object.__setattr__(self, "_approach", approach.scaled(factor) if approach is not None else None)
        object.__setattr__(self, "_scan", scan.scaled(factor))

    @property
    def normal(self) -> FloatArray:
        """Unit normal of the patch on the scanning side."""
        n = np.cross(self.scan_edge, self.step_edge)
        unit: FloatArray = n / np.linalg.norm(n)
        return unit

    @property
    def passes(self) -> int:
        """Passes of the whole scan (``pass_index`` picks one of them)."""
        return len(self._lines)

    @property
    def approach_duration(self) -> float:
        return self._approach.duration if self._approach is not None else 0.0

    @property
    def duration(self) -> float:
        return self.approach_duration + self._scan.duration

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        flat, shape = _flat(t)
        p, A = self._scan.pose(flat - self.approach_duration)
        if self._approach is not None:
            early = flat < self.approach_duration
            if np.any(early):
                p[early], A[early] = self._approach.pose(flat[early])
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = _flat(t)
        out = self._scan.twist(flat - self.approach_duration)
        if self._approach is not None:
            early = flat < self.approach_duration
            out[early] = self._approach.twist(flat[early])
        return out.reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> RasterPath:
        return dataclasses.replace(self, duration_override=_positive(duration, "duration"))

    def pass_paths(self) -> list[RasterPath]:
        """One path per pass (approach and that pass): the tasks of a tuning over the passes."""
        return [dataclasses.replace(self, pass_index=i, duration_override=None) for i in range(self.passes)]

    def summary(self) -> dict[str, Any]:
        return {
            "type": self.kind,
            "duration": self.duration,
            "approach_duration": self.approach_duration,
            "passes": self.passes if self.pass_index is None else 1,
            "pass_index": self.pass_index,
            "scan_length": self._scan.total_length,
            "scan_speed": self._scan.total_length / max(self._scan.duration - self._scan.ramp_time, 1e-300),
            "standoff": self.standoff,
            "line_spacing": self.line_spacing,
            "turn_radius": self.turn_radius,
        }


def _turn(
    end: FloatArray, start: FloatArray, heading: FloatArray, step: FloatArray, n: FloatArray, radius: float
) -> list[tuple[Any, ...]]:
    """Pieces from the end of a pass (moving along ``heading``) to the start of the next one
    (``end + spacing step``, moving along ``-heading``): a quarter circle out of the patch, a
    straight piece along ``step`` (none when the radius is half the spacing) and a quarter circle
    back; both circles turn about ``n`` when heading along the scan edge, else about ``-n``."""
    spacing = float(np.linalg.norm(start - end))
    axis = n if float(heading.dot(np.cross(n, step))) < 0.0 else -n
    c1 = end + radius * step
    c2 = start - radius * step
    out: list[tuple[Any, ...]] = [("arc", c1, axis, end, math.pi / 2.0)]
    if spacing - 2.0 * radius > MIN_SEGMENT:
        out.append(("line", c1 + radius * heading, c2 + radius * heading))
    out.append(("arc", c2, axis, c2 + radius * heading, math.pi / 2.0))
    return out


PATH_TYPES: dict[str, type[LinePath] | type[WaypointPath] | type[ArcPath] | type[RasterPath]] = {
    "line": LinePath,
    "waypoints": WaypointPath,
    "arc": ArcPath,
    "raster": RasterPath,
}


def make_path(kind: str, start_position: ArrayLike, start_attitude: ArrayLike, **spec: Any) -> Path:
    """The path of type ``kind`` (see :data:`PATH_TYPES`) from the start pose; ``spec`` are the
    type's keyword arguments (an arc given by ``via_position`` and ``end_position`` goes through
    :meth:`ArcPath.through`)."""
    if kind not in PATH_TYPES:
        raise ParameterError("type", f"unknown path type {kind!r}; valid: {', '.join(PATH_TYPES)}")
    if kind == "arc" and "via_position" in spec:
        via, end = spec.pop("via_position"), spec.pop("end_position")
        return ArcPath.through(start_position, start_attitude, via, end, **spec)
    path: Path = PATH_TYPES[kind](np.asarray(start_position, dtype=float), np.asarray(start_attitude, dtype=float), **spec)
    return path
