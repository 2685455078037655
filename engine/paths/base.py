"""What the path types share: the :class:`Path` protocol and registry (:func:`register`), time
laws, geodesics, Cartesian speed limits and rest-to-rest segments."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal, Protocol, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError, finite_array
from engine.spatial import FloatArray, exp_so3, is_rotation, log_so3

Profile = Literal["trapezoidal", "quintic"]
PROFILES: tuple[str, ...] = ("trapezoidal", "quintic")
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


#: The path types by name, filled by :func:`register` as each type's module is imported.
PATH_TYPES: dict[str, Any] = {}
P = TypeVar("P")


def register(cls: type[P]) -> type[P]:
    """Class decorator: make the path type ``cls`` (its ``kind``) known to :func:`engine.paths.make_path`.
    The type's ``build(start_position, start_attitude, **spec)`` constructs it from its keyword
    arguments (default: the class itself)."""
    kind = cls.kind  # type: ignore[attr-defined]
    if kind in PATH_TYPES and PATH_TYPES[kind] is not cls:
        raise ValueError(f"two path types are named {kind!r}")
    PATH_TYPES[kind] = cls
    return cls


class OnTimeLaw(Protocol):
    """A path on one :func:`time_law` (line, arc): its duration, ramp time and profile."""

    kind: ClassVar[str]

    @property
    def duration(self) -> float: ...

    @property
    def ramp_time(self) -> float: ...

    @property
    def profile(self) -> str: ...


# --- shared pieces ----------------------------------------------------------------------------


def flatten_times(t: ArrayLike) -> tuple[FloatArray, tuple[int, ...]]:
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


def check_position(value: ArrayLike, name: str) -> FloatArray:
    return finite_array(value, (3,), name)


def check_attitude(value: ArrayLike, name: str) -> FloatArray:
    arr = finite_array(value, (3, 3), name)
    if not is_rotation(arr):
        raise ParameterError(name, "must be a rotation matrix")
    return arr


def check_direction(value: ArrayLike, name: str) -> FloatArray:
    arr = np.array(finite_array(value, (3,), name))
    norm = float(np.linalg.norm(arr))
    if norm < 1e-12:
        raise ParameterError(name, "must be a non-zero vector")
    unit = arr / norm
    unit.setflags(write=False)
    return unit


def check_positive(value: float, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ParameterError(name, "must be finite and > 0")
    return value


def override_scale(duration: float | None, natural: float) -> float:
    """The time scale of an optional duration override (``duration / natural``)."""
    if duration is None:
        return 1.0
    return check_positive(duration, "duration") / natural


def retimed_law(path: OnTimeLaw, duration: float) -> tuple[float, float]:
    """``(duration, ramp_time)`` of a path on one :func:`time_law` retimed to ``duration``: its
    ramp scales with it."""
    duration = check_positive(duration, "duration")
    return duration, min(path.ramp_time * (duration / path.duration), duration / 2.0)


def law_summary(path: OnTimeLaw) -> dict[str, Any]:
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
            object.__setattr__(self, name, check_positive(getattr(self, name), f"max_{name}"))

    def move_duration(self, length: float, angle: float) -> float:
        """Duration (s) of a quintic move of ``length`` m and ``angle`` rad within the limits."""
        return max(
            QUINTIC_PEAK_SPEED * length / self.speed,
            math.sqrt(QUINTIC_PEAK_ACCELERATION * length / self.acceleration),
            QUINTIC_PEAK_SPEED * angle / self.angular_speed,
            math.sqrt(QUINTIC_PEAK_ACCELERATION * angle / self.angular_acceleration),
        )


@dataclass(frozen=True)
class Segments:
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

    def scaled(self, factor: float) -> Segments:
        return Segments(self.p, self.A, self.durations * factor)

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
