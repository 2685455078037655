"""Collision geometry: shapes on robots, obstacles and the clearance of a task's scene.

Each shape converts itself to the engine's (:func:`engine.geometry.shape_from_dict`, the one
validation of shapes: the schema states the same bounds for the document); a ``mesh`` obstacle
names a stored mesh (``/v1/meshes``), whose convex hull is the shape."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextvars import ContextVar
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal, Union

import numpy as np
from pydantic import Field

from engine.bounds import MAX_LENGTH_M
from engine.errors import ParameterError
from engine.geometry import MAX_HULL_VERTICES, MAX_SHAPES, Scene, Shape, shape_from_dict
from service.schemas.common import Input, Quaternion, Vec3

#: m: the smallest size of a shape.
MIN_SIZE_M = 1e-6
Size = Annotated[float, Field(ge=MIN_SIZE_M, le=MAX_LENGTH_M)]
Size3 = Annotated[list[Size], Field(min_length=3, max_length=3)]

#: How a ``mesh`` obstacle finds its stored mesh's hull (``(V, 3)`` m, in the mesh's frame): set
#: by the use cases that convert requests (they hold the database), for the conversion's duration.
MESH_HULLS: ContextVar[Callable[[str], np.ndarray] | None] = ContextVar("mesh_hulls", default=None)


class ShapeSchema(Input):
    """A convex shape's request schema: its ``type`` and its parameters (SI)."""

    kind: ClassVar[str]

    def to_engine(self) -> Shape:
        return shape_from_dict(self.model_dump(exclude_none=True), "")

    def locate(self, field: str | Sequence[str | int]) -> list[str | int]:
        """As :meth:`Input.locate`, under the shape's type (as the schema's own errors are)."""
        return [self.kind, *super().locate(field)]


class SphereIn(ShapeSchema):
    """A sphere."""

    kind: ClassVar[str] = "sphere"
    type: Literal["sphere"] = Field(description="the shape type")
    radius_m: Size = Field(description="radius, m")
    position_m: Vec3 | None = Field(default=None, description="centre, m (default the origin of the frame)")


class CapsuleIn(ShapeSchema):
    """All points within `radius_m` of the segment from `from_m` to `to_m`."""

    kind: ClassVar[str] = "capsule"
    type: Literal["capsule"] = Field(description="the shape type")
    radius_m: Size = Field(description="radius, m")
    from_m: Vec3 = Field(description="one end of the segment, m")
    to_m: Vec3 = Field(description="the other end, m")


class BoxIn(ShapeSchema):
    """A box, its edges along its own axes (the frame's axes turned by `quaternion`)."""

    kind: ClassVar[str] = "box"
    type: Literal["box"] = Field(description="the shape type")
    size_m: Size3 = Field(description="edge lengths along the box's x, y and z axes, m")
    position_m: Vec3 | None = Field(default=None, description="centre, m (default the origin of the frame)")
    quaternion: Quaternion | None = Field(default=None, description="attitude [w, x, y, z] (default identity)")


class CylinderIn(ShapeSchema):
    """A solid cylinder along its own z axis, centred on `position_m`."""

    kind: ClassVar[str] = "cylinder"
    type: Literal["cylinder"] = Field(description="the shape type")
    radius_m: Size = Field(description="radius, m")
    length_m: Size = Field(description="length along its axis, m")
    position_m: Vec3 | None = Field(default=None, description="centre, m (default the origin of the frame)")
    quaternion: Quaternion | None = Field(default=None, description="attitude [w, x, y, z] (default identity)")


class ConvexIn(ShapeSchema):
    """The convex hull of vertices (in the shape's own frame)."""

    kind: ClassVar[str] = "convex"
    type: Literal["convex"] = Field(description="the shape type")
    vertices_m: list[Vec3] = Field(
        min_length=4, max_length=MAX_HULL_VERTICES, description="points whose convex hull is the shape, m (not all coplanar)"
    )
    position_m: Vec3 | None = Field(default=None, description="where the vertices' origin is, m (default the frame's origin)")
    quaternion: Quaternion | None = Field(default=None, description="attitude [w, x, y, z] (default identity)")


class MeshIn(ShapeSchema):
    """A stored mesh (`POST /v1/meshes`, STL or OBJ): its convex hull, posed by `position_m` and
    `quaternion` (the mesh's coordinates are taken as metres)."""

    kind: ClassVar[str] = "mesh"
    type: Literal["mesh"] = Field(description="the shape type")
    mesh_id: str = Field(pattern=r"^[0-9a-f]{32}$", description="the stored mesh's id (32 hex digits)")
    position_m: Vec3 | None = Field(default=None, description="where the mesh's origin is, m (default the frame's origin)")
    quaternion: Quaternion | None = Field(default=None, description="attitude [w, x, y, z] (default identity)")

    def to_engine(self) -> Shape:
        hulls = MESH_HULLS.get()
        if hulls is None:
            raise ParameterError("mesh_id", "mesh obstacles are resolved by the service (POST /v1/meshes first)")
        vertices = hulls(self.mesh_id)
        data: dict[str, Any] = {"type": "convex", "vertices_m": np.asarray(vertices).tolist()}
        if self.position_m is not None:
            data["position_m"] = self.position_m
        if self.quaternion is not None:
            data["quaternion"] = self.quaternion
        return shape_from_dict(data, "")


if TYPE_CHECKING:
    BodyShapeIn = ShapeSchema
    ObstacleIn = ShapeSchema
else:
    BodyShapeIn = Annotated[Union[SphereIn, CapsuleIn, BoxIn, CylinderIn, ConvexIn], Field(discriminator="type")]  # noqa: UP007
    ObstacleIn = Annotated[Union[SphereIn, CapsuleIn, BoxIn, CylinderIn, ConvexIn, MeshIn], Field(discriminator="type")]  # noqa: UP007


def shapes_of(shapes: list[Any] | None, field: str) -> tuple[Shape, ...]:
    """The engine's shapes of a list of shape schemas; errors name ``<field>[i].<name>``."""
    out = []
    for i, shape in enumerate(shapes or []):
        try:
            out.append(shape.to_engine())
        except ParameterError as exc:
            raise exc.within(f"{field}[{i}]") from None
    return tuple(out)


class SceneIn(Input):
    """What the task works among: obstacles in the task's world frame (the frame of the paths:
    the carrier starts at rest at its origin with the identity attitude), and how the plan keeps
    clear of them, of the carrier and between links. Checked when the robot has collision
    shapes."""

    obstacles: list[ObstacleIn] = Field(default_factory=list, max_length=MAX_SHAPES, description="the obstacles, world frame")
    influence_distance_m: float = Field(
        default=0.1,
        gt=0,
        le=MAX_LENGTH_M,
        description="pairs closer than this, m, are avoided within the step: a velocity damper in the `bounded` "
        "inverse's QP, a push apart for the `clearance` secondary objective (must exceed the task's `clearance_m`)",
    )
    avoidance_gain: float = Field(
        default=0.5,
        gt=0,
        le=1,
        description="the fraction of a close pair's distance above `clearance_m` that one step may consume "
        "(dimensionless, (0, 1]; the velocity damper's gain)",
    )

    def to_engine(self, clearance: float) -> Scene:
        return Scene(
            obstacles=shapes_of(self.obstacles, "obstacles"),
            clearance=clearance,
            influence_distance=self.influence_distance_m,
            avoidance_gain=self.avoidance_gain,
        )
