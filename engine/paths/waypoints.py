"""Poses visited in order, rest to rest on quintic laws: ``waypoints``."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.paths.base import (
    MIN_SEGMENT,
    Segments,
    SpeedLimits,
    check_attitude,
    check_position,
    check_positive,
    displacement_twists,
    flatten_times,
    override_scale,
    register,
)
from engine.spatial import FloatArray, rotation_angle

MAX_WAYPOINTS = 100


@register
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
    _segments: Segments = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        start_p = check_position(self.start_position, "start_position")
        start_A = check_attitude(self.start_attitude, "start_attitude")
        positions = np.asarray(self.positions, dtype=float)
        attitudes = np.asarray(self.attitudes, dtype=float)
        count = positions.shape[0] if positions.ndim == 2 else 0
        if not 1 <= count <= MAX_WAYPOINTS:
            raise ParameterError("waypoints", f"expected 1 to {MAX_WAYPOINTS} waypoints")
        if attitudes.shape != (count, 3, 3):
            raise ParameterError("waypoints", "expected one attitude per waypoint")
        for i in range(count):
            check_position(positions[i], f"waypoints[{i}].position")
            check_attitude(attitudes[i], f"waypoints[{i}].attitude")
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
                check_positive(d, f"segment_durations[{i}]")
        else:
            durations = np.array([self.limits.move_duration(float(L), float(a)) for L, a in zip(lengths, angles, strict=True)])
        durations = durations * override_scale(self.duration_override, float(np.sum(durations)))
        object.__setattr__(self, "_segments", Segments(p, A, durations))

    @property
    def duration(self) -> float:
        return self._segments.duration

    @property
    def segment_times(self) -> FloatArray:
        """Arrival time (s) at each waypoint ``(W,)``."""
        return np.cumsum(self._segments.durations)

    def pose(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        flat, shape = flatten_times(t)
        p, A = self._segments.pose(flat)
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = flatten_times(t)
        return self._segments.twist(flat).reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> WaypointPath:
        return dataclasses.replace(self, duration_override=check_positive(duration, "duration"))

    def summary(self) -> dict[str, Any]:
        return {
            "type": self.kind,
            "duration": self.duration,
            "waypoints": int(self.positions.shape[0]),
            "segment_durations": self._segments.durations.tolist(),
            "length": float(np.sum(np.linalg.norm(self._segments.dp, axis=1))),
            "rotation_angle": float(np.sum(np.linalg.norm(self._segments.phi, axis=1))),
        }
