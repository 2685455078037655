"""The interactive 3D view's scene of a stored plan (``GET /plans/{plan_id}/scene.json``, a web
route): what the page cannot take from the JSON API directly. The page reads the trajectory
(times, base pose, desired and achieved end-effector paths) from ``GET /v1/plans/{plan_id}`` and
the robot from ``GET /v1/robots/{robot_id}``; the arm's joint positions need the forward
kinematics, computed here for at most :data:`MAX_FRAMES` evenly spread samples
(:func:`service.figures.arm_frames`, one batch of :func:`engine.kinematics.kinematics_batch`),
with the carrier's box and the plan's obstacles (triangle meshes, world frame)."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from engine.geometry import Shape
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


def triangles(shape: Shape) -> dict[str, Any]:
    """A shape (world frame) as a triangle mesh for the page: ``positions_m (V, 3)`` and
    ``faces (F, 3)`` (trimesh's primitives, or the hull of a convex shape's vertices)."""
    import trimesh  # for the 3D view only

    if shape.type == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=shape.radius)
    elif shape.type == "capsule":
        mesh = trimesh.creation.capsule(height=2.0 * shape.dims[0], radius=shape.radius, count=[16, 8])
    elif shape.type == "box":
        mesh = trimesh.creation.box(extents=2.0 * shape.dims)
    elif shape.type == "cylinder":
        mesh = trimesh.creation.cylinder(radius=shape.dims[0], height=2.0 * shape.dims[1], sections=24)
    else:
        assert shape.vertices is not None  # a convex shape
        mesh = trimesh.convex.convex_hull(shape.vertices)
    positions = shape.position + np.asarray(mesh.vertices) @ shape.rotation.T
    return {"positions_m": np.round(positions, DECIMALS).tolist(), "faces": np.asarray(mesh.faces).tolist()}


def carrier_of(base: dict[str, Any]) -> dict[str, Any]:
    """The carrier's collision box when the robot has one, else the box of its inertia."""
    box = base.get("collision_box")
    if isinstance(box, dict) and box.get("size_m"):
        centre = box.get("center_m") or [0.0, 0.0, 0.0]
        return {"size_m": list(box["size_m"]), "axes": np.eye(3).tolist(), "com_offset_m": list(centre)}
    return carrier_box(base)


def scene(db: Database, plan_id: str) -> dict[str, Any]:
    """The scene of ``plan_id``: frames (sample ``index``, ``t_s`` and the arm's ``points_m``,
    each ``(n + 2, 3)``: base CoM, joints 1..n, end effector, world frame), the carrier's box,
    obstacles. 404 for an unknown plan."""
    with db.session() as session:
        row = session.get(Plan, plan_id)
        if row is None:
            raise NotFoundError("plan", plan_id)
        data = figures.plan_data(plan_id, functools.partial(figure_cases.plan_data, session, row))
        shapes = figure_cases.obstacles(session, row.request)
    index, lines = figures.arm_frames(data, MAX_FRAMES)
    points = np.round(np.stack(lines), DECIMALS) if lines else np.zeros((0, 0, 3))
    robot = data.robot or {}
    return {
        "plan_id": plan_id,
        "joints": int(data.q.shape[1]) if data.q.ndim == 2 else 0,
        "frames": {"index": index.tolist(), "t_s": data.t[index].tolist(), "points_m": points.tolist()},
        "carrier": carrier_of(robot.get("base") or {}),
        "obstacles": [triangles(shape) for shape in shapes if shape is not None],  # a deleted mesh's is left out
    }
