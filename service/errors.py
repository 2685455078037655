"""RFC 9457 problem details (``application/problem+json``) for every error response."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

PROBLEM_JSON = "application/problem+json"
PROBLEM_BASE = "https://spacearm.example/problems/"

TITLES = {
    400: "Bad Request",
    404: "Not Found",
    405: "Method Not Allowed",
    409: "Conflict",
    422: "Unprocessable Content",
    500: "Internal Server Error",
}
TYPES = {404: "not-found", 409: "conflict", 422: "validation-error", 500: "internal-error"}


class ApiError(Exception):
    def __init__(self, status: int, detail: str, *, type_: str | None = None, title: str | None = None, **extra: Any) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.type_ = type_
        self.title = title
        self.extra = extra


class NotFoundError(ApiError):
    def __init__(self, kind: str, ident: str) -> None:
        super().__init__(404, f"{kind} {ident!r} does not exist")


class ConflictError(ApiError):
    def __init__(self, detail: str) -> None:
        super().__init__(409, detail)


class ApiValidationError(ApiError):
    def __init__(self, detail: str, errors: list[dict[str, Any]]) -> None:
        super().__init__(422, detail, errors=[_error_item(e) for e in errors])


def _error_item(e: dict[str, Any]) -> dict[str, Any]:
    loc = [p for p in e.get("loc", [])]
    return {"field": _path(loc), "loc": loc, "message": e.get("msg", "")}


def _path(loc: list[Any]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def problem(
    status: int, detail: str, *, type_: str | None = None, title: str | None = None, instance: str | None = None, **extra: Any
) -> JSONResponse:
    body: dict[str, Any] = {
        "type": type_ or (PROBLEM_BASE + TYPES[status] if status in TYPES else "about:blank"),
        "title": title or TITLES.get(status, "Error"),
        "status": status,
        "detail": detail,
    }
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, media_type=PROBLEM_JSON)


def install(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        return problem(exc.status, exc.detail, type_=exc.type_, title=exc.title, instance=request.url.path, **exc.extra)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        items = [{"loc": list(e.get("loc", [])), "msg": e.get("msg", "")} for e in exc.errors()]
        errors = [_error_item(e) for e in items]
        detail = "; ".join(f"{e['field']}: {e['message']}" for e in errors) or "invalid request"
        return problem(422, detail, instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        return problem(exc.status_code, str(exc.detail), instance=request.url.path)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        return problem(500, f"unexpected error: {type(exc).__name__}", instance=request.url.path)


class FieldError(BaseModel):
    field: str = Field(description="dotted path of the offending field, e.g. body.task.q0_deg")
    loc: list[str | int]
    message: str


class Problem(BaseModel):
    """RFC 9457 problem details."""

    type: str = Field(description="URI identifying the problem type")
    title: str
    status: int
    detail: str = Field(description="what went wrong, for a person")
    instance: str | None = None
    errors: list[FieldError] | None = Field(default=None, description="validation errors with field paths (422)")


def responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries for the given error codes (problem+json, see :func:`problem_openapi`)."""
    desc = {404: "unknown id", 409: "conflict: the resource's state does not allow it", 422: "invalid body or parameters"}
    return {code: {"description": desc.get(code, TITLES.get(code, "error")), "model": Problem} for code in codes}


def problem_openapi(app: FastAPI) -> None:
    """Error responses are ``application/problem+json`` of the ``Problem`` schema in the document."""
    from fastapi.openapi.utils import get_openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        doc = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes, tags=app.openapi_tags
        )
        ref = {"$ref": "#/components/schemas/Problem"}
        for item in doc.get("paths", {}).values():
            for op in item.values():
                for code, resp in op.get("responses", {}).items():
                    if code.isdigit() and int(code) >= 400:
                        resp["content"] = {PROBLEM_JSON: {"schema": ref}}
                        if code == "422":
                            resp["description"] = "invalid body or parameters (field paths in `errors`)"
        schemas = doc.setdefault("components", {}).setdefault("schemas", {})
        for unused in ("HTTPValidationError", "ValidationError"):
            schemas.pop(unused, None)
        app.openapi_schema = doc
        return doc

    app.openapi = openapi  # type: ignore[method-assign]
