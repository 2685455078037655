"""A circular arc: ``arc``."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.paths.base import (
    MIN_SEGMENT,
    check_attitude,
    check_direction,
    check_position,
    check_timing,
    displacement_twists,
    flatten_times,
    law_summary,
    register,
    retimed_law,
    time_law,
)
from engine.spatial import FloatArray, cross, exp_so3

ARC_ATTITUDES: tuple[str, ...] = ("tangent", "fixed")


@register
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
        object.__setattr__(self, "start_position", check_position(self.start_position, "start_position"))
        object.__setattr__(self, "start_attitude", check_attitude(self.start_attitude, "start_attitude"))
        object.__setattr__(self, "centre", check_position(self.centre, "centre"))
        object.__setattr__(self, "axis", check_direction(self.axis, "axis"))
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
    def build(cls, start_position: ArrayLike, start_attitude: ArrayLike, **spec: Any) -> ArcPath:
        """The arc from ``centre``, ``axis`` and ``angle``, or through ``via_position`` to ``end_position``."""
        if "via_position" in spec:
            via, end = spec.pop("via_position"), spec.pop("end_position")
            return cls.through(start_position, start_attitude, via, end, **spec)
        return cls(np.asarray(start_position, dtype=float), np.asarray(start_attitude, dtype=float), **spec)

    @classmethod
    def through(
        cls, start_position: ArrayLike, start_attitude: ArrayLike, via: ArrayLike, end: ArrayLike, **options: Any
    ) -> ArcPath:
        """The arc from the start position through ``via`` to ``end`` (three points of a circle)."""
        p1 = check_position(start_position, "start_position")
        p2 = check_position(via, "via_position")
        p3 = check_position(end, "end_position")
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
        flat, shape = flatten_times(t)
        s, _ = time_law(flat, self.duration, self.ramp_time, self.profile)
        R = exp_so3((s * self.angle)[:, None] * self.axis)
        p = self.centre + R @ (self.start_position - self.centre)
        A = R @ self.start_attitude if self.attitude == "tangent" else np.broadcast_to(self.start_attitude, R.shape).copy()
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = flatten_times(t)
        _, sdot = time_law(flat, self.duration, self.ramp_time, self.profile)
        w = (sdot * self.angle)[:, None] * self.axis
        p, _ = self.pose(flat)
        v = cross(w, p - self.centre)
        out = np.concatenate([v, w if self.attitude == "tangent" else np.zeros_like(w)], axis=1)
        return out.reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> ArcPath:
        duration, ramp_time = retimed_law(self, duration)
        return dataclasses.replace(self, duration=duration, ramp_time=ramp_time)

    def summary(self) -> dict[str, Any]:
        return {
            **law_summary(self),
            "radius": self.radius,
            "angle": self.angle,
            "length": self.radius * abs(self.angle),
            "attitude": self.attitude,
        }
