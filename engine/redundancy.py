"""Secondary objectives for redundant arms (more joints than the task tracks: n > 6 for a pose,
n > 3 for a position), resolved in the null space of the tracked Jacobian by the planner's
kernel (:mod:`engine.kernels.redundancy`), so the end-effector motion is that of the primary
inverse whatever the objective asks.

- ``min_base_rotation`` (``gain`` in [0, 1], 1 = the full minimiser): of the joint rates that
  give the same end-effector twist, the one whose carrier angular velocity is smallest (the
  reaction null-space idea of Nenchev and Yoshida: keep the carrier, and the sensors and
  antennas that point from it, still).
- ``joint_centering`` (``gain`` in 1/s): null-space rates ``-gain (q - q_c)`` pulling each joint
  towards the middle of its position limits (its start value when it has none).
- ``clearance`` (``gain`` in 1/s): null-space rates pushing apart every pair of shapes closer
  than the scene's influence distance (each pair's distance raised at ``gain`` times its
  shortfall, :mod:`engine.geometry`); it needs collision geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from engine.errors import ParameterError
from engine.kernels import redundancy as redundancy_kernels
from engine.model import RobotModel
from engine.spatial import FloatArray

MAX_CENTERING_GAIN = 100.0  # 1/s


class SecondaryObjective(Protocol):
    """A null-space objective: its kernel number and gain."""

    name: ClassVar[str]
    objective_id: ClassVar[int]
    gain: float


@dataclass(frozen=True)
class MinBaseRotation:
    """Choose the null-space motion that minimises the carrier's angular velocity; ``gain`` in
    [0, 1] scales the correction (1 = the least-squares minimiser)."""

    name: ClassVar[str] = "min_base_rotation"
    objective_id: ClassVar[int] = redundancy_kernels.MIN_BASE_ROTATION
    gain: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and 0.0 <= self.gain <= 1.0):
            raise ParameterError("secondary.gain", f"must be in [0, 1] for {self.name}, got {self.gain!r}")


@dataclass(frozen=True)
class JointCentering:
    """Pull each joint towards the middle of its limits in the null space; ``gain`` in 1/s."""

    name: ClassVar[str] = "joint_centering"
    objective_id: ClassVar[int] = redundancy_kernels.JOINT_CENTERING
    gain: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and 0.0 <= self.gain <= MAX_CENTERING_GAIN):
            raise ParameterError(
                "secondary.gain", f"must be in [0, {MAX_CENTERING_GAIN:g}] 1/s for {self.name}, got {self.gain!r}"
            )


@dataclass(frozen=True)
class Clearance:
    """Push close pairs of shapes apart in the null space; ``gain`` in 1/s."""

    name: ClassVar[str] = "clearance"
    objective_id: ClassVar[int] = redundancy_kernels.CLEARANCE
    gain: float = 2.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gain) and 0.0 <= self.gain <= MAX_CENTERING_GAIN):
            raise ParameterError(
                "secondary.gain", f"must be in [0, {MAX_CENTERING_GAIN:g}] 1/s for {self.name}, got {self.gain!r}"
            )


SECONDARY_OBJECTIVES: dict[str, type] = {cls.name: cls for cls in (MinBaseRotation, JointCentering, Clearance)}


def make_secondary(name: str, gain: float | None = None) -> SecondaryObjective:
    """The objective ``name`` (one of :data:`SECONDARY_OBJECTIVES`) with ``gain`` (its default
    if None)."""
    cls = SECONDARY_OBJECTIVES.get(name)
    if cls is None:
        raise ParameterError("secondary.objective", f"unknown objective {name!r}; valid: {', '.join(SECONDARY_OBJECTIVES)}")
    objective: SecondaryObjective = cls() if gain is None else cls(gain=float(gain))
    return objective


def joint_centres(model: RobotModel, q0: FloatArray) -> FloatArray:
    """``(n,)`` the middle of each joint's limits, or its start value ``q0`` where a side is
    unlimited (rad or m)."""
    lower, upper = model.lower_limits, model.upper_limits
    both = np.isfinite(lower) & np.isfinite(upper)
    centre: FloatArray = np.ascontiguousarray(np.where(both, 0.5 * (np.where(both, lower, 0.0) + np.where(both, upper, 0.0)), q0))
    return centre
