"""Meshes: uploaded STL or OBJ files, stored once, whose convex hulls are obstacles of task scenes
(``{"type": "mesh", "mesh_id": ...}``). An upload is read behind the plan admission (reading and
checking a mesh costs CPU like a plan)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response, status

from service import figures
from service.deps import DbDep, Limit, Offset, SessionDep, SessionRoute, SettingsDep, run_admitted
from service.errors import ApiValidationError, Problem, responses
from service.schemas.common import ID_PATTERN
from service.schemas.meshes import MeshFormat, MeshList, MeshOut
from service.usecases import meshes, rows

router = APIRouter(prefix="/v1/meshes", tags=["meshes"], route_class=SessionRoute)
MeshId = Annotated[str, Path(pattern=ID_PATTERN, description="a mesh's id (32 hex digits)", examples=["0" * 32])]

UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "description": "the file: binary or ASCII STL, or OBJ (at most 512 KiB)",
        "content": {
            media: {"schema": {"type": "string", "format": "binary"}}
            for media in ("model/stl", "model/obj", "application/octet-stream")
        },
    }
}


@router.post(
    "",
    operation_id="create_mesh",
    response_model=MeshOut,
    status_code=status.HTTP_201_CREATED,
    summary="Store a mesh (STL or OBJ) for the obstacles of task scenes",
    description="The body is the file (at most 512 KiB, else a 413); its format is `format`, else its "
    "`Content-Type` (`model/stl`, `model/obj`). The mesh must be one closed surface (watertight) with finite "
    "coordinates within +-1 km (taken as metres), and its convex hull, which is the obstacle a scene checks, at most "
    "512 vertices; otherwise a 422 says why. The same file is stored once: posting it again answers 200 with the "
    "stored mesh. 201 with the mesh and its `Location`.",
    responses={
        **responses(422),
        413: {"description": "the file is over 512 KiB (or the body over 1 MiB)", "model": Problem},
        200: {"description": "the same file was stored already: the stored mesh", "model": MeshOut},
    },
    openapi_extra=UPLOAD_BODY,
)
async def create_mesh(
    request: Request,
    settings: SettingsDep,
    response: Response,
    format: Annotated[MeshFormat | None, Query(description="the file's format (default: from `Content-Type`)")] = None,
    name: Annotated[str | None, Query(min_length=1, max_length=200, description="a name for the mesh")] = None,
) -> MeshOut:
    media = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
    fmt = format or meshes.MEDIA_TYPES.get(media)
    if fmt is None:
        raise ApiValidationError.at(
            ["query", "format"],
            "the file's format is needed",
            detail="give ?format=stl or ?format=obj (or Content-Type model/stl or model/obj)",
        )
    content = await request.body()

    def work() -> tuple[MeshOut, bool]:
        with request.app.state.db.session() as session:
            return meshes.create(session, settings.storage_quota_bytes, content, fmt, name)

    stored, new = await run_admitted(request, work, "plans and uploads")
    response.headers["Location"] = f"/v1/meshes/{stored.id}"
    if not new:
        response.status_code = status.HTTP_200_OK
    return stored


@router.get(
    "",
    operation_id="list_meshes",
    response_model=MeshList,
    summary="List meshes",
    description="Stored meshes, oldest first, `limit` at a time from `offset`; `total` counts them all.",
    responses=responses(422),
)
def list_meshes(session: SessionDep, limit: Limit = 50, offset: Offset = 0) -> MeshList:
    return meshes.listing(session, limit, offset)


@router.get(
    "/{mesh_id}",
    operation_id="get_mesh",
    response_model=MeshOut,
    summary="Get a mesh",
    description="A stored mesh: what was uploaded and its convex hull's size.",
    responses=responses(404, 422),
)
def get_mesh(mesh_id: MeshId, session: SessionDep) -> MeshOut:
    return meshes.get(session, mesh_id)


@router.delete(
    "/{mesh_id}",
    operation_id="delete_mesh",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Delete a mesh",
    description="204 once deleted. Plans that used it keep their results; planning their requests again needs the mesh.",
    responses=responses(404, 422),
)
def delete_mesh(mesh_id: MeshId, db: DbDep) -> Response:
    from service.models import Mesh

    rows.delete(db, Mesh, mesh_id, "mesh")
    figures.forget_obstacles()  # stored plans' scene figures drew it
    return Response(status_code=status.HTTP_204_NO_CONTENT)
