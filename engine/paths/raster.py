"""A boustrophedon scan of a rectangular patch: ``raster``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
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
    check_direction,
    check_position,
    check_positive,
    displacement_twists,
    flatten_times,
    override_scale,
    register,
    time_law,
)
from engine.spatial import FloatArray, cross, exp_so3, rotation_angle

MAX_PASSES = 200


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


@register
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
    _approach: Segments | None = field(init=False, repr=False, compare=False)
    _scan: _Curve = field(init=False, repr=False, compare=False)
    _lines: tuple[tuple[FloatArray, FloatArray], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        start_p = check_position(self.start_position, "start_position")
        start_A = check_attitude(self.start_attitude, "start_attitude")
        corner = check_position(self.corner, "corner")
        u = check_position(self.scan_edge, "scan_edge")
        v = check_position(self.step_edge, "step_edge")
        if float(np.linalg.norm(u)) < MIN_SEGMENT:
            raise ParameterError("scan_edge", "must be a non-zero vector")
        if float(np.linalg.norm(v)) < MIN_SEGMENT:
            raise ParameterError("step_edge", "must be a non-zero vector")
        width = float(np.linalg.norm(v))
        if abs(float(u.dot(v))) > 1e-6 * float(np.linalg.norm(u)) * width:
            raise ParameterError("step_edge", "must be perpendicular to scan_edge (a rectangular patch)")
        spacing = check_positive(self.line_spacing, "line_spacing")
        if spacing > width * (1.0 + 1e-12):
            raise ParameterError("line_spacing", f"{spacing:g} m is wider than the patch ({width:g} m): no second pass")
        passes = math.floor(width / spacing + 1e-9) + 1
        if passes > MAX_PASSES:
            raise ParameterError("line_spacing", f"gives {passes} passes, at most {MAX_PASSES} allowed")
        standoff = check_positive(self.standoff, "standoff")
        speed = check_positive(self.scan_speed, "scan_speed")
        acceleration = check_positive(self.scan_acceleration, "scan_acceleration")
        radius = spacing / 2.0 if self.turn_radius is None else check_positive(self.turn_radius, "turn_radius")
        if radius > spacing / 2.0 * (1.0 + 1e-12):
            raise ParameterError("turn_radius", f"must be at most half the line spacing ({spacing / 2.0:g} m)")
        axis = check_direction(self.sensor_axis, "sensor_axis")
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
            approach = Segments(knots_p, knots_A, np.array([self.approach.move_duration(reach, turn)]))
        natural = scan.duration + (approach.duration if approach is not None else 0.0)
        factor = override_scale(self.duration_override, natural)
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
        flat, shape = flatten_times(t)
        p, A = self._scan.pose(flat - self.approach_duration)
        if self._approach is not None:
            early = flat < self.approach_duration
            if np.any(early):
                p[early], A[early] = self._approach.pose(flat[early])
        return p.reshape(shape + (3,)), A.reshape(shape + (3, 3))

    def twist(self, t: ArrayLike) -> FloatArray:
        flat, shape = flatten_times(t)
        out = self._scan.twist(flat - self.approach_duration)
        if self._approach is not None:
            early = flat < self.approach_duration
            out[early] = self._approach.twist(flat[early])
        return out.reshape(shape + (6,))

    def step_twists(self, times: FloatArray, dt: float) -> FloatArray:
        return displacement_twists(*self.pose(times), dt)

    def retimed(self, duration: float) -> RasterPath:
        return dataclasses.replace(self, duration_override=check_positive(duration, "duration"))

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
