"""Meshes for task scenes: an uploaded STL or OBJ file is read with trimesh, checked (one closed
surface, finite numbers within the scene's bounds, a hull the kernels can afford) and stored
once, with its convex hull, which is the obstacle's shape (:mod:`engine.geometry`). The hulls are
what the requests' ``mesh`` obstacles resolve to (:func:`hulls`)."""

from __future__ import annotations

import contextlib
import hashlib
import io
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from engine.bounds import MAX_LENGTH_M
from engine.errors import ParameterError
from engine.geometry import MAX_HULL_VERTICES
from service.errors import ApiError, ApiValidationError, field_error
from service.infra.quota import check_quota
from service.models import Mesh, utcnow
from service.schemas.geometry import MESH_HULLS
from service.schemas.meshes import MeshFormat, MeshList, MeshOut
from service.usecases import rows

#: Media types of the formats (``Content-Type`` of an upload, besides ``?format=``).
MEDIA_TYPES: dict[str, MeshFormat] = {"model/stl": "stl", "model/obj": "obj", "application/sla": "stl"}
MIN_EXTENT_M = 1e-4
#: Bytes of an uploaded mesh file, at most (the request limit is larger: this one's 413 names it).
MAX_MESH_BYTES = 512 * 1024


def _invalid(reason: str, where: str = "body") -> ApiValidationError:
    return ApiValidationError.at([where], reason)


def read(content: bytes, fmt: MeshFormat) -> tuple[Any, np.ndarray]:
    """The mesh of an uploaded file and its convex hull's vertices ``(V, 3)`` m; a 422 saying
    what is wrong with it."""
    import trimesh  # 0.2 s of imports, for uploads only

    if not content:
        raise _invalid("the file is empty")
    if len(content) > MAX_MESH_BYTES:  # a 413 as for any body over a limit (it was a 422 under 1 MiB)
        reason = f"the file has {len(content)} bytes, more than the {MAX_MESH_BYTES} a mesh may have"
        raise ApiError(413, f"body: {reason}", errors=[field_error(["body"], reason)])
    try:
        # unprocessed first: processing drops the vertices that are not finite, and then the mesh
        # read as not closed instead of as not finite
        mesh = trimesh.load(io.BytesIO(content), file_type=fmt, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds for a file it cannot read
        raise _invalid(f"not a readable {fmt.upper()} file ({type(exc).__name__}: {exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise _invalid(f"the {fmt.upper()} file holds no triangles")
    vertices = np.asarray(mesh.vertices, dtype=float)
    if not np.all(np.isfinite(vertices)) or np.abs(vertices).max() > MAX_LENGTH_M:
        raise _invalid(f"every coordinate must be finite and within +-{MAX_LENGTH_M:g} m")
    mesh.process()  # merges duplicate vertices, as loading with process=True does
    vertices = np.asarray(mesh.vertices, dtype=float)
    if float(np.ptp(vertices, axis=0).min()) < MIN_EXTENT_M:
        raise _invalid("the mesh is flat: an obstacle needs a volume")
    if not mesh.is_watertight:
        raise _invalid("the mesh is not closed (not watertight): an obstacle must be a closed surface")
    hull = np.asarray(mesh.convex_hull.vertices, dtype=float)
    if hull.shape[0] > MAX_HULL_VERTICES:
        raise _invalid(
            f"its convex hull has {hull.shape[0]} vertices, more than the {MAX_HULL_VERTICES} a scene may hold: "
            "simplify the mesh (its hull is what the planner checks)"
        )
    return mesh, hull


def out(row: Mesh) -> MeshOut:
    return MeshOut(
        id=row.id,
        name=row.name,
        format=row.format,  # type: ignore[arg-type]
        size_bytes=row.size_bytes,
        vertex_count=row.vertex_count,
        face_count=row.face_count,
        hull_vertex_count=len(row.hull) // 24,
        bounds_m=row.bounds,
        created_at=row.created_at,
    )


def create(session: Session, quota_bytes: int | None, content: bytes, fmt: MeshFormat, name: str | None) -> tuple[MeshOut, bool]:
    """Store an uploaded mesh (once: the same bytes give the stored one back). Returns it and
    whether it is new."""
    mesh_id = hashlib.sha256(fmt.encode() + b"\0" + content).hexdigest()[:32]
    stored = session.get(Mesh, mesh_id)
    if stored is not None:
        return out(stored), False
    mesh, hull = read(content, fmt)
    vertices = np.asarray(mesh.vertices, dtype=float)
    hull_bytes = np.ascontiguousarray(hull, dtype="<f8").tobytes()
    check_quota(session, quota_bytes, len(hull_bytes))
    row = Mesh(
        id=mesh_id,
        name=name or fmt,
        format=fmt,
        size_bytes=len(content),
        vertex_count=len(vertices),
        face_count=len(mesh.faces),
        hull=hull_bytes,
        bounds=[vertices.min(axis=0).tolist(), vertices.max(axis=0).tolist()],
        created_at=utcnow(),
    )
    session.add(row)
    session.flush()
    return out(row), True


def get(session: Session, mesh_id: str) -> MeshOut:
    return out(rows.load(session, Mesh, mesh_id, "mesh"))


def listing(session: Session, limit: int, offset: int) -> MeshList:
    found = session.scalars(select(Mesh).order_by(Mesh.created_at, Mesh.id).limit(limit).offset(offset)).all()
    total = session.scalar(select(func.count()).select_from(Mesh)) or 0
    return MeshList(items=[out(row) for row in found], total=int(total))


def hull_of(session: Session, mesh_id: str) -> np.ndarray:
    """The convex hull ``(V, 3)`` m of a stored mesh; a ``ParameterError`` on ``mesh_id`` when
    there is none (the request's location names the obstacle)."""
    row = session.get(Mesh, mesh_id)
    if row is None:
        raise ParameterError("mesh_id", f"no stored mesh {mesh_id!r} (POST /v1/meshes first)")
    return np.frombuffer(row.hull, dtype="<f8").reshape(-1, 3)


@contextlib.contextmanager
def hulls(session: Session) -> Iterator[Callable[[str], np.ndarray]]:
    """Within: a request's ``mesh`` obstacles resolve to the stored meshes' hulls."""

    def resolve(mesh_id: str) -> np.ndarray:
        return hull_of(session, mesh_id)

    token = MESH_HULLS.set(resolve)
    try:
        yield resolve
    finally:
        MESH_HULLS.reset(token)
