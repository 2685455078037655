"""The paper's straight line (eq. 2): ``line``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from engine.paths.base import check_attitude, check_position, check_timing, geodesic, law_summary, register, retimed_law, time_law
from engine.spatial import FloatArray, log_so3


@register
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
            object.__setattr__(self, name, check_position(getattr(self, name), name))
        for name in ("start_attitude", "target_attitude"):
            object.__setattr__(self, name, check_attitude(getattr(self, name), name))
        object.__setattr__(self, "duration", float(self.duration))
        object.__setattr__(self, "ramp_time", float(self.ramp_time))
        check_timing(self.duration, self.ramp_time, self.profile)
        object.__setattr__(self, "_phi", log_so3(self.target_attitude @ self.start_attitude.T))

    @property
    def rotation_vector(self) -> FloatArray:
        return self._phi

    @property
    def direction(self) -> FloatArray:
        return np.concatenate([self.target_position - self.start_position, self._phi])

    def path_parameter(self, times: ArrayLike) -> tuple[FloatArray, FloatArray]:
        return time_law(times, self.duration, self.ramp_time, self.profile)

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        s, _ = self.path_parameter(t)
        return geodesic(self.start_position, self.start_attitude, self.target_position - self.start_position, self._phi, s)

    def twist(self, t: ArrayLike) -> FloatArray:
        _, sdot = self.path_parameter(t)
        out: FloatArray = sdot[..., None] * self.direction
        return out

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        """``(s_{k+1} - s_k) / dt`` times the line's direction: the exact displacement (the
        rotation about one fixed axis composes additively)."""
        s, _ = self.path_parameter(times)
        ds = np.append(np.diff(s), 0.0)
        out: FloatArray = (ds / dt)[:, None] * self.direction
        return out

    def retimed(self, duration: float) -> LinePath:
        duration, ramp_time = retimed_law(self, duration)
        return dataclasses.replace(self, duration=duration, ramp_time=ramp_time)

    def summary(self) -> dict[str, Any]:
        return {
            **law_summary(self),
            "length": float(np.linalg.norm(self.target_position - self.start_position)),
            "rotation_angle": float(np.linalg.norm(self._phi)),
        }
