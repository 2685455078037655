"""The interactive 3D view's scene of a stored plan (``GET /plans/{plan_id}/scene.json``, a web
route): what the page cannot take from the JSON API directly. The page reads the trajectory
(times, base pose, desired and achieved end-effector paths) from ``GET /v1/plans/{plan_id}`` and
the robot from ``GET /v1/robots/{robot_id}``; the arm's joint positions need the forward
kinematics, computed here for at most :data:`MAX_FRAMES` evenly spread samples
(:func:`service.figures.arm_frames`, one batch of :func:`engine.kinematics.kinematics_batch`),
with the carrier's box and the plan's obstacles."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from service import figures
from service.errors import NotFoundError
from service.infra.db import Database
from service.models import Plan
from service.usecases import figures as figure_cases

#: Frames of the arm sent to the page at most (a 20,000-step plan is strided to these).
MAX_FRAMES = 600
#: Positions are sent rounded to this many decimals of a metre (0.01 mm).
DECIMALS = 5


def carrier_box(base: dict[str, Any]) -> dict[str, Any]:
    """The carrier drawn as the box of uniform density with its mass and inertia: edges ``size_m``
    from the principal moments (``I_1 = m (b^2 + c^2) / 12``, ...), along ``axes`` (the principal
    axes, columns in the base frame). An inertia no box has (a rod's) is drawn as a slab."""
    mass = float(base.get("mass", 1.0))
    inertia = np.asarray(base.get("inertia", np.eye(3)), dtype=float)
    moments, axes = np.linalg.eigh((inertia + inertia.T) / 2.0)
    if np.linalg.det(axes) < 0:  # a rotation, not a reflection
        axes[:, 2] = -axes[:, 2]
    squares = 6.0 * (moments.sum() - 2.0 * moments) / mass  # a^2 = 6 (I_2 + I_3 - I_1) / m
    size = np.sqrt(np.maximum(squares, 0.0))
    size = np.maximum(size, 0.05 * size.max()) if size.max() > 0 else np.full(3, 0.5)
    return {"size_m": np.round(size, 4).tolist(), "axes": np.round(axes, 6).tolist(), "com_offset_m": [0.0, 0.0, 0.0]}


def obstacles(request: dict[str, Any]) -> list[dict[str, Any]]:
    """The obstacles of the plan's task, for plans that have geometry (spheres
    ``{"type": "sphere", "center_m", "radius_m"}`` and boxes ``{"type": "box", "center_m",
    "size_m", "quaternion"}``); none today."""
    task = request.get("task") or {}
    found = task.get("obstacles") or []
    return [o for o in found if isinstance(o, dict) and o.get("type") in ("sphere", "box")]


def scene(db: Database, plan_id: str) -> dict[str, Any]:
    """The scene of ``plan_id``: frames (sample ``index``, ``t_s`` and the arm's ``points_m``,
    each ``(n + 2, 3)``: base CoM, joints 1..n, end effector, world frame), the carrier's box,
    obstacles. 404 for an unknown plan."""
    with db.session() as session:
        row = session.get(Plan, plan_id)
        if row is None:
            raise NotFoundError("plan", plan_id)
        data = figures.plan_data(plan_id, functools.partial(figure_cases.plan_data, session, row))
        request = dict(row.request or {})
    index, lines = figures.arm_frames(data, MAX_FRAMES)
    points = np.round(np.stack(lines), DECIMALS) if lines else np.zeros((0, 0, 3))
    robot = data.robot or {}
    return {
        "plan_id": plan_id,
        "joints": int(data.q.shape[1]) if data.q.ndim == 2 else 0,
        "frames": {"index": index.tolist(), "t_s": data.t[index].tolist(), "points_m": points.tolist()},
        "carrier": carrier_box(robot.get("base") or {}),
        "obstacles": obstacles(request),
    }
