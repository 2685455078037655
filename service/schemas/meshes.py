"""Meshes: uploaded STL or OBJ files whose convex hulls are obstacles of task scenes."""

from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import Field

from service.schemas.common import Output

MeshFormat = Literal["stl", "obj"]


class MeshOut(Output):
    """A stored mesh: what was uploaded and the convex hull the scenes use."""

    id: str = Field(description="the mesh's id (32 hex digits, from its bytes: the same file is stored once)")
    name: str = Field(description="its name (the `name` given, else the format)")
    format: MeshFormat = Field(description="the file's format")
    size_bytes: int = Field(description="the file's size, bytes")
    vertex_count: int = Field(description="the mesh's vertices (count)")
    face_count: int = Field(description="the mesh's triangles (count)")
    hull_vertex_count: int = Field(description="the vertices of its convex hull (count), which is the obstacle's shape")
    bounds_m: list[list[float]] = Field(description="the mesh's axis-aligned bounds, m: [[x, y, z] min, [x, y, z] max]")
    created_at: datetime = Field(description="when it was stored (UTC)")


class MeshList(Output):
    items: list[MeshOut] = Field(description="this page of meshes, oldest first")
    total: int = Field(description="number of meshes stored")
