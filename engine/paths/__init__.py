"""Path strategies: time-parameterised end-effector pose trajectories (what a task follows).

A path gives, for ``t`` in ``[0, duration]`` s (and held after), the desired pose ``p_d(t) (3,)``
m and ``A_d(t) (3, 3)`` (end effector -> world), the instantaneous desired twist
``[v; w] (6,)`` (m/s, rad/s, world axes, ``dA_d/dt = [w]x A_d``) and, at the planner's sample
times, the per-step displacement twists the kernels consume: ``v_k = (p_{k+1} - p_k) / dt`` and
``w_k = log(A_{k+1} A_k^T) / dt`` (world axes), zero at the last sample, so that
``p_k + v_k dt = p_{k+1}`` and ``exp([w_k dt]x) A_k = A_{k+1}`` exactly (to rounding).

Every path starts at the end-effector pose of the task's initial configuration. Each type is a
module of this package whose class is decorated with :func:`engine.paths.base.register`; the
modules are imported here, so a new type is its module alone. Chosen by name only at the
boundary (:func:`make_path`):

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

import importlib
import pkgutil
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import ParameterError
from engine.paths.arc import ARC_ATTITUDES, ArcPath
from engine.paths.base import PATH_TYPES, PROFILES, Path, Profile, SpeedLimits, time_law
from engine.paths.line import LinePath
from engine.paths.raster import MAX_PASSES, RasterPath
from engine.paths.waypoints import MAX_WAYPOINTS, WaypointPath

for _module in pkgutil.iter_modules(__path__):  # every path type registers itself on import
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = [
    "ARC_ATTITUDES",
    "MAX_PASSES",
    "MAX_WAYPOINTS",
    "PATH_TYPES",
    "PROFILES",
    "ArcPath",
    "LinePath",
    "Path",
    "Profile",
    "RasterPath",
    "SpeedLimits",
    "WaypointPath",
    "make_path",
    "time_law",
]


def make_path(kind: str, start_position: ArrayLike, start_attitude: ArrayLike, **spec: Any) -> Path:
    """The path of type ``kind`` (see :data:`PATH_TYPES`) from the start pose; ``spec`` are the
    type's keyword arguments (its ``build`` classmethod, or its constructor)."""
    if kind not in PATH_TYPES:
        raise ParameterError("type", f"unknown path type {kind!r}; valid: {', '.join(PATH_TYPES)}")
    cls = PATH_TYPES[kind]
    build = getattr(cls, "build", cls)
    path: Path = build(np.asarray(start_position, dtype=float), np.asarray(start_attitude, dtype=float), **spec)
    return path
