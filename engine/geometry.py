"""Collision geometry: convex shapes on the robot's bodies and obstacles in the task's world, the
pairs that can collide, and distances (thin wrappers over :mod:`engine.kernels.geometry`).

A shape is a convex core swept by a sphere (see the kernel module): ``sphere`` (a point and a
radius), ``capsule`` (a segment and a radius), ``box``, ``cylinder`` (along its local z axis)
and ``convex`` (the convex hull of vertices). On a body its pose is relative to the body's
centre of mass, in the body's frame (the model's frames: parallel to the carrier at q = 0, see
:mod:`engine.model`); an obstacle's is in the task's world frame. Shapes are read from and
written to dictionaries with SI field names (``radius_m``, ``position_m``, ``quaternion``
``[w, x, y, z]``, ...), the form of robot parameter sets and of the API.

Pairs checked (:func:`collision_pairs`): each link's shapes against every obstacle; each link
against the carrier except link 1, which is mounted on it; links at least two apart (adjacent
links share a joint and always touch there); the carrier against every obstacle.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from engine.bounds import MAX_LENGTH_M
from engine.errors import ParameterError, finite_array
from engine.kernels import geometry as kernels
from engine.spatial import FloatArray, matrix_to_quaternion, quaternion_to_matrix

SHAPE_TYPES: tuple[str, ...] = ("sphere", "capsule", "box", "cylinder", "convex")
#: Vertices of one convex shape (its hull's; more are refused).
MAX_HULL_VERTICES = 512
#: Shapes on a robot or in a scene.
MAX_SHAPES = 64
_KINDS = {
    "sphere": kernels.POINT,
    "capsule": kernels.SEGMENT,
    "box": kernels.BOX,
    "cylinder": kernels.CYLINDER,
    "convex": kernels.HULL,
}
_MIN_SIZE = 1e-6  # m: a dimension below this is not a shape


def _positive(value: Any, field_name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field_name, "expected a number") from exc
    if not math.isfinite(number) or not _MIN_SIZE <= number <= MAX_LENGTH_M:
        raise ParameterError(field_name, f"must be finite, at least {_MIN_SIZE:g} m and at most {MAX_LENGTH_M:g} m")
    return number


def _rotation(value: Any, field_name: str) -> FloatArray:
    if value is None:
        return np.eye(3)
    q = finite_array(value, (4,), field_name)
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 2.0:
        raise ParameterError(field_name, "must be a unit quaternion [w, x, y, z]")
    return quaternion_to_matrix(q / norm)


@dataclass(frozen=True, eq=False)
class Shape:
    """A convex shape: its type, the sweeping ``radius`` (m; 0 for box, cylinder and convex),
    its pose (``position (3,)`` m, ``rotation (3, 3)`` whose columns are its axes) in its
    frame, and its size: ``half_extents (3,)`` m of a box, ``(radius, half_length, 0)`` of a
    cylinder, ``(half_length, 0, 0)`` of a capsule's segment along its local z; ``vertices
    (V, 3)`` m of a convex shape, in its own frame. Build with :func:`shape_from_dict`."""

    type: str
    radius: float = 0.0
    position: FloatArray = field(default_factory=lambda: np.zeros(3))
    rotation: FloatArray = field(default_factory=lambda: np.eye(3))
    dims: FloatArray = field(default_factory=lambda: np.zeros(3))
    vertices: FloatArray | None = None

    @property
    def bounding_radius(self) -> float:
        """m: the radius about ``position`` of a sphere holding the whole shape."""
        core = {
            "sphere": 0.0,
            "capsule": float(self.dims[0]),
            "box": float(np.linalg.norm(self.dims)),
            "cylinder": float(math.hypot(self.dims[0], self.dims[1])),
            "convex": float(np.linalg.norm(self.vertices, axis=1).max()) if self.vertices is not None else 0.0,
        }[self.type]
        return core + self.radius

    def to_dict(self) -> dict[str, Any]:
        """The dictionary :func:`shape_from_dict` reads back to this shape."""
        quaternion = matrix_to_quaternion(self.rotation).tolist()
        if self.type == "sphere":
            return {"type": "sphere", "radius_m": self.radius, "position_m": self.position.tolist()}
        if self.type == "capsule":
            axis = self.rotation[:, 2] * self.dims[0]
            return {
                "type": "capsule",
                "radius_m": self.radius,
                "from_m": (self.position - axis).tolist(),
                "to_m": (self.position + axis).tolist(),
            }
        if self.type == "box":
            return {
                "type": "box",
                "size_m": (2.0 * self.dims).tolist(),
                "position_m": self.position.tolist(),
                "quaternion": quaternion,
            }
        if self.type == "cylinder":
            return {
                "type": "cylinder",
                "radius_m": float(self.dims[0]),
                "length_m": float(2.0 * self.dims[1]),
                "position_m": self.position.tolist(),
                "quaternion": quaternion,
            }
        assert self.vertices is not None
        return {
            "type": "convex",
            "vertices_m": self.vertices.tolist(),
            "position_m": self.position.tolist(),
            "quaternion": quaternion,
        }

    def row(self, body: int, vertex_offset: int = 0) -> FloatArray:
        """The kernel's row of this shape on ``body`` (``kernels.WORLD`` for an obstacle), its
        vertices (if convex) starting at ``vertex_offset`` of the vertex array."""
        out = np.zeros(kernels.SHAPE_WIDTH)
        out[kernels.BODY] = body
        out[kernels.KIND] = _KINDS[self.type]
        out[kernels.RADIUS] = self.radius
        out[kernels.POS : kernels.POS + 3] = self.position
        out[kernels.ROT : kernels.ROT + 9] = self.rotation.ravel()
        out[kernels.DIMS : kernels.DIMS + 3] = self.dims
        if self.type == "convex":
            assert self.vertices is not None
            out[kernels.DIMS] = vertex_offset
            out[kernels.DIMS + 1] = self.vertices.shape[0]
            out[kernels.DIMS + 2] = 0.0
        out[kernels.BOUND] = self.bounding_radius
        return out


def capsule(start: ArrayLike, end: ArrayLike, radius: float) -> Shape:
    """The capsule of ``radius`` m around the segment from ``start (3,)`` to ``end (3,)`` m (a
    sphere when they coincide)."""
    a = np.asarray(start, dtype=float)
    b = np.asarray(end, dtype=float)
    half = 0.5 * float(np.linalg.norm(b - a))
    centre = 0.5 * (a + b)
    if half < 0.5 * _MIN_SIZE:
        return Shape("sphere", radius, centre)
    z = (b - a) / (2.0 * half)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return Shape("capsule", radius, centre, np.column_stack([x, np.cross(z, x), z]), np.array([half, 0.0, 0.0]))


def _convex_vertices(value: Any, field_name: str) -> FloatArray:
    try:
        verts = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(field_name, "expected a list of [x, y, z] vertices") from exc
    if verts.ndim != 2 or verts.shape[1] != 3 or not 4 <= verts.shape[0] <= MAX_HULL_VERTICES:
        raise ParameterError(field_name, f"expected 4 to {MAX_HULL_VERTICES} vertices [x, y, z]")
    if not np.all(np.isfinite(verts)) or np.abs(verts).max() > MAX_LENGTH_M:
        raise ParameterError(field_name, f"every number must be finite and within +-{MAX_LENGTH_M:g} m")
    centred = verts - verts.mean(axis=0)
    if np.linalg.svd(centred, compute_uv=False)[-1] < _MIN_SIZE:
        raise ParameterError(field_name, "the vertices are flat (coplanar or fewer): a convex shape needs a volume")
    return verts


def shape_from_dict(data: Mapping[str, Any], field_name: str = "shape") -> Shape:
    """A shape from its dictionary (see the module docstring); a ``ParameterError`` names the
    field at fault (``<field_name>.radius_m``)."""
    prefix = f"{field_name}." if field_name else ""  # "" for a shape named by its caller
    if not isinstance(data, Mapping):
        raise ParameterError(field_name or "shape", "expected an object")
    kind = data.get("type")
    if kind not in SHAPE_TYPES:
        raise ParameterError(f"{prefix}type", f"must be one of {', '.join(SHAPE_TYPES)}")
    allowed = {
        "sphere": {"type", "radius_m", "position_m"},
        "capsule": {"type", "radius_m", "from_m", "to_m"},
        "box": {"type", "size_m", "position_m", "quaternion"},
        "cylinder": {"type", "radius_m", "length_m", "position_m", "quaternion"},
        "convex": {"type", "vertices_m", "position_m", "quaternion"},
    }[kind]
    extra = sorted(set(data) - allowed)
    if extra:
        raise ParameterError(f"{prefix}{extra[0]}", f"not a field of a {kind} (its fields: {', '.join(sorted(allowed))})")

    def point(name: str) -> FloatArray:
        value = data.get(name, [0.0, 0.0, 0.0] if name == "position_m" else None)
        if value is None:
            raise ParameterError(f"{prefix}{name}", "required")
        return finite_array(value, (3,), f"{prefix}{name}", MAX_LENGTH_M).copy()

    if kind == "capsule":
        return capsule(point("from_m"), point("to_m"), _positive(data.get("radius_m"), f"{prefix}radius_m"))
    position = point("position_m")
    if kind == "sphere":
        return Shape("sphere", _positive(data.get("radius_m"), f"{prefix}radius_m"), position)
    rotation = _rotation(data.get("quaternion"), f"{prefix}quaternion")
    if kind == "box":
        size = finite_array(data.get("size_m"), (3,), f"{prefix}size_m")
        for i, edge in enumerate(size):
            _positive(edge, f"{prefix}size_m[{i}]")
        return Shape("box", 0.0, position, rotation, 0.5 * size)
    if kind == "cylinder":
        r = _positive(data.get("radius_m"), f"{prefix}radius_m")
        length = _positive(data.get("length_m"), f"{prefix}length_m")
        return Shape("cylinder", 0.0, position, rotation, np.array([r, 0.5 * length, 0.0]))
    vertices = _convex_vertices(data.get("vertices_m"), f"{prefix}vertices_m")
    return Shape("convex", 0.0, position, rotation, np.zeros(3), vertices)


def shapes_from_list(value: Any, field_name: str) -> tuple[Shape, ...]:
    """Shapes from a list of dictionaries (None: none)."""
    if value is None:
        return ()
    if not isinstance(value, list) or len(value) > MAX_SHAPES:
        raise ParameterError(field_name, f"expected a list of at most {MAX_SHAPES} shapes")
    return tuple(shape_from_dict(item, f"{field_name}[{i}]") for i, item in enumerate(value))


@dataclass(frozen=True, eq=False)
class Scene:
    """What a task's end effector works among: ``obstacles`` (world frame), the smallest
    distance allowed between any pair (``clearance`` m), and how avoidance acts within the step:
    pairs closer than ``influence_distance`` m constrain the ``bounded`` inverse (their distance
    may shrink by at most ``avoidance_gain`` of its excess over the clearance per step) and
    drive the ``clearance`` null-space objective."""

    obstacles: tuple[Shape, ...] = ()
    clearance: float = 0.0
    influence_distance: float = 0.1
    avoidance_gain: float = 0.5

    def __post_init__(self) -> None:
        if len(self.obstacles) > MAX_SHAPES:
            raise ParameterError("obstacles", f"at most {MAX_SHAPES} obstacles")
        if not (math.isfinite(self.clearance) and 0.0 <= self.clearance <= MAX_LENGTH_M):
            raise ParameterError("clearance", "must be finite and >= 0")
        if not (math.isfinite(self.influence_distance) and self.clearance < self.influence_distance <= MAX_LENGTH_M):
            raise ParameterError("influence_distance", "must be finite and larger than the clearance")
        if not (math.isfinite(self.avoidance_gain) and 0.0 < self.avoidance_gain <= 1.0):
            raise ParameterError("avoidance_gain", "must be in (0, 1]")


#: Owner of a shape in pair names: the carrier, a link, or obstacle ``i``.
CARRIER = "carrier"


@dataclass(frozen=True, eq=False)
class Geometry:
    """A robot's and a scene's shapes as the kernels take them: ``shapes (S, SHAPE_WIDTH)``
    rows, the convex shapes' ``vertices (V, 3)``, the ``pairs (P, 2)`` of shape indices checked,
    ``owners`` (a name per shape: a link's name, ``carrier`` or ``obstacle<i>``) and the
    scene's settings ``(clearance, influence_distance, avoidance_gain)``."""

    shapes: FloatArray
    vertices: FloatArray
    pairs: np.ndarray
    owners: tuple[str, ...]
    settings: FloatArray

    @property
    def active(self) -> bool:
        """Whether there is any pair to check."""
        return self.pairs.shape[0] > 0

    def pair_names(self, index: int) -> tuple[str, str]:
        return self.names[index]

    @cached_property
    def names(self) -> tuple[tuple[str, str], ...]:
        """The owners of every pair, in the pairs' order."""
        return tuple((self.owners[int(a)], self.owners[int(b)]) for a, b in self.pairs)

    def kernel_args(self) -> tuple[FloatArray, FloatArray, np.ndarray, FloatArray]:
        return self.shapes, self.vertices, self.pairs, self.settings


def collision_pairs(bodies: Sequence[int]) -> np.ndarray:
    """``(P, 2)`` indices of the shapes that can collide, from each shape's body
    (``kernels.WORLD`` for obstacles, 0 the carrier, ``i`` link ``i``): see the module
    docstring."""
    pairs = []
    for i, a in enumerate(bodies):
        for j in range(i + 1, len(bodies)):
            b = bodies[j]
            lo, hi = min(a, b), max(a, b)
            if hi == kernels.WORLD:
                continue  # two obstacles
            if lo == kernels.WORLD or (lo == 0 and hi >= 2) or (lo >= 1 and hi - lo >= 2):
                pairs.append((i, j))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def build_geometry(
    link_shapes: Sequence[Sequence[Shape]], carrier_shapes: Sequence[Shape], link_names: Sequence[str], scene: Scene
) -> Geometry:
    """The kernels' geometry of a robot's shapes (``link_shapes[i]`` on link ``i + 1``) and a
    scene."""
    rows, vertices, owners, bodies = [], [], [], []
    offset = 0

    def add(shape: Shape, body: int, owner: str) -> None:
        nonlocal offset
        rows.append(shape.row(body, offset))
        if shape.vertices is not None:
            vertices.append(shape.vertices)
            offset += shape.vertices.shape[0]
        owners.append(owner)
        bodies.append(body)

    for shape in carrier_shapes:
        add(shape, 0, CARRIER)
    for i, shapes in enumerate(link_shapes):
        for shape in shapes:
            add(shape, i + 1, link_names[i])
    for k, shape in enumerate(scene.obstacles):
        add(shape, kernels.WORLD, f"obstacle{k}")
    robot_shapes = len(rows) - len(scene.obstacles)
    pairs = collision_pairs(bodies) if robot_shapes else np.zeros((0, 2), dtype=np.int64)
    return Geometry(
        shapes=np.array(rows, dtype=float).reshape(-1, kernels.SHAPE_WIDTH),
        vertices=np.concatenate(vertices) if vertices else np.zeros((1, 3)),
        pairs=np.ascontiguousarray(pairs),
        owners=tuple(owners),
        settings=np.array([scene.clearance, scene.influence_distance, scene.avoidance_gain]),
    )


def posed(shape: Shape, rotation: ArrayLike | None = None, position: ArrayLike | None = None) -> FloatArray:
    """The kernel row of ``shape`` moved by ``x -> rotation x + position`` (its frame's pose)."""
    out = np.empty((1, kernels.SHAPE_WIDTH))
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    p = np.zeros(3) if position is None else np.asarray(position, dtype=float)
    # as the planner poses a body's shape: body 0 with attitude R and CoM p
    kernels.pose_into(shape.row(0)[None], 0, R[None], p[None], np.eye(3), np.zeros(3), out, 0)
    return out[0]


@dataclass(frozen=True)
class Distance:
    """A signed distance (m; negative when the shapes overlap: minus how far apart they must
    move to touch) and the closest points of the two shapes' cores, ``(2, 3)`` m (the shapes'
    surfaces are ``radius`` further in); of cores that intersect, their deepest points (moving
    ``b`` from its point towards ``a``'s separates them fastest)."""

    distance: float
    points: FloatArray


def distance(
    a: Shape,
    b: Shape,
    pose_a: tuple[ArrayLike, ArrayLike] | None = None,
    pose_b: tuple[ArrayLike, ArrayLike] | None = None,
) -> Distance:
    """The signed distance between shapes ``a`` and ``b``, each moved by its pose ``(R (3, 3),
    p (3,))`` (default: as given)."""
    row_a = posed(a, *(pose_a or (None, None)))
    row_b = posed(b, *(pose_b or (None, None)))
    parts = [s.vertices for s in (a, b) if s.vertices is not None]
    if a.vertices is not None and b.vertices is not None:
        row_b[kernels.DIMS] = a.vertices.shape[0]
    vertices = np.ascontiguousarray(np.concatenate(parts)) if parts else np.zeros((1, 3))
    out = np.empty(1)
    witness = np.empty((1, 2, 3))
    kernels.distances_many(row_a[None], row_b[None], vertices, out, witness)
    return Distance(float(out[0]), witness[0])


def shape_outline(shape: Shape, segments: int = 24) -> list[FloatArray]:
    """Polylines ``(K, 3)`` m that outline ``shape`` where it is (for drawing): a box's 12 edges,
    three great circles of a sphere, a capsule's axis and the circles at its ends, a cylinder's
    rims and four sides, a convex shape's hull edges."""
    R, c = shape.rotation, shape.position
    angle = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)

    def placed(points: FloatArray) -> FloatArray:
        return c + points @ R.T

    if shape.type == "sphere":
        r = shape.radius
        return [placed(r * ring[:, perm]) for perm in ([0, 1, 2], [0, 2, 1], [2, 0, 1])]
    if shape.type == "capsule":
        h, r = shape.dims[0], shape.radius
        axis = np.array([[0.0, 0.0, -h], [0.0, 0.0, h]])
        return [placed(axis), placed(r * ring + [0.0, 0.0, -h]), placed(r * ring + [0.0, 0.0, h])]
    if shape.type == "box":
        corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * shape.dims
        edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
        return [placed(corners[[i, j]]) for i, j in edges]
    if shape.type == "cylinder":
        r, h = shape.dims[0], shape.dims[1]
        rims = [placed(r * ring + [0.0, 0.0, z]) for z in (-h, h)]
        sides = [placed(np.array([[r * np.cos(a), r * np.sin(a), -h], [r * np.cos(a), r * np.sin(a), h]])) for a in angle[:-1:6]]
        return rims + sides
    assert shape.vertices is not None
    from scipy.spatial import ConvexHull  # only for drawing hulls

    hull = ConvexHull(shape.vertices)
    lines: set[tuple[int, int]] = set()
    for simplex in hull.simplices:
        for a, b in zip(simplex, np.roll(simplex, 1), strict=True):
            lines.add((min(int(a), int(b)), max(int(a), int(b))))
    return [placed(shape.vertices[list(line)]) for line in sorted(lines)]
