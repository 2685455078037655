"""RFC 9457 problem details (``application/problem+json``) for every error response."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field, ValidationError
from sqlalchemy.exc import DataError, DBAPIError
from sqlalchemy.exc import TimeoutError as PoolTimeoutError
from starlette.exceptions import HTTPException as StarletteHTTPException

from engine.errors import ParameterError
from service.infra.db import DatabaseUnavailableError, is_locked, unavailable_reason
from service.schemas.common import API_LOCATION, dotted_path, field_path

PROBLEM_JSON = "application/problem+json"
PROBLEM_BASE = "https://spacearm.example/problems/"
MAX_OFFSET = 1_000_000_000  # list offsets (larger ones overflow SQLite integers)

TITLES = {
    400: "Bad Request",
    401: "Unauthorized",
    404: "Not Found",
    405: "Method Not Allowed",
    406: "Not Acceptable",
    408: "Request Timeout",
    409: "Conflict",
    413: "Content Too Large",
    415: "Unsupported Media Type",
    422: "Unprocessable Content",
    429: "Too Many Requests",
    431: "Request Header Fields Too Large",
    500: "Internal Server Error",
    503: "Service Unavailable",
    507: "Insufficient Storage",
}
TYPES = {
    401: "unauthorized",
    404: "not-found",
    406: "not-acceptable",
    408: "request-timeout",
    409: "conflict",
    413: "content-too-large",
    415: "unsupported-media-type",
    422: "validation-error",
    429: "too-many-requests",
    431: "request-head-too-large",
    500: "internal-error",
    503: "unavailable",
    507: "insufficient-storage",
}

#: Retry-After (s) of a 503 for a locked database, and for one that is unavailable for a while
RETRY_LOCKED_S = 1
RETRY_UNAVAILABLE_S = 5


class ApiError(Exception):
    def __init__(
        self,
        status: int,
        detail: str,
        *,
        type_: str | None = None,
        title: str | None = None,
        headers: dict[str, str] | None = None,
        **extra: Any,
    ) -> None:
        super().__init__(detail)
        self.status = status
        self.headers = headers
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


class NotAcceptableError(ApiError):
    """``Accept`` names none of the media types a resource has (``available``)."""

    def __init__(self, detail: str, available: list[str]) -> None:
        super().__init__(406, detail, headers={"Vary": "Accept"}, available=available)  # the answer depends on Accept


class UnsupportedMediaTypeError(ApiError):
    """The body's ``Content-Type`` is not one the resource reads."""

    def __init__(self, detail: str) -> None:
        super().__init__(415, detail)


def body_invalid(exc: ValidationError) -> RequestValidationError:
    """A raw body's validation errors under ``body``, as FastAPI reports those of a typed body."""
    return RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in exc.errors()])


class TooManyRequestsError(ApiError):
    def __init__(self, detail: str, retry_after_s: int) -> None:
        super().__init__(429, detail, headers={"Retry-After": str(retry_after_s)})


class BodyTooLargeError(StarletteHTTPException):
    """Raised from the body-size guard while FastAPI reads a body (FastAPI re-raises HTTP exceptions)."""

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"request body larger than {limit} bytes")


def field_error(loc: list[Any], msg: str) -> dict[str, Any]:
    return _error_item({"loc": loc, "msg": msg})


class ApiValidationError(ApiError):
    def __init__(self, detail: str, errors: list[dict[str, Any]]) -> None:
        super().__init__(422, detail, errors=[_error_item(e) for e in errors])

    @classmethod
    def at(cls, loc: list[Any], msg: str, *, detail: str | None = None) -> ApiValidationError:
        """The 422 of the field at ``loc`` (``["query", "fields"]``): its ``detail`` (default
        ``msg``) after the field's path, as ``errors[].field`` names it."""
        return cls(f"{dotted_path(loc)}: {detail or msg}", [{"loc": loc, "msg": msg}])


def _json_invalid(e: Any) -> dict[str, Any] | None:
    """A body that is not JSON, as an error of the body: FastAPI places it at ``("body", offset)``,
    which read as an array index (``body[22]``), with the parser's reason left out."""
    loc = e.get("loc", ())
    if e.get("type") != "json_invalid" or len(loc) != 2 or loc[0] != "body" or not isinstance(loc[1], int):
        return None
    reason = (e.get("ctx") or {}).get("error") or "not valid JSON"
    return {"loc": ["body"], "msg": f"not valid JSON: {reason} at char {loc[1]} (counted from 0)"}


def _error_item(e: dict[str, Any]) -> dict[str, Any]:
    loc = [p for p in e.get("loc", [])]
    return {"field": dotted_path(loc), "loc": loc, "message": e.get("msg", "")}


def problem(
    status: int,
    detail: str,
    *,
    type_: str | None = None,
    title: str | None = None,
    instance: str | None = None,
    headers: Mapping[str, str] | None = None,
    **extra: Any,
) -> JSONResponse:
    body = problem_body(status, detail, type_=type_, title=title)
    if instance:
        body["instance"] = instance
    body.update(extra)
    return JSONResponse(body, status_code=status, media_type=PROBLEM_JSON, headers=dict(headers) if headers else None)


def problem_body(status: int, detail: str, *, type_: str | None = None, title: str | None = None) -> dict[str, Any]:
    """The members every problem has: ``type`` (of :data:`TYPES` by default), ``title``, ``status``
    and ``detail``."""
    return {
        "type": type_ or (PROBLEM_BASE + TYPES[status] if status in TYPES else "about:blank"),
        "title": title or TITLES.get(status, "Error"),
        "status": status,
        "detail": detail,
    }


def install(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        return problem(
            exc.status, exc.detail, type_=exc.type_, title=exc.title, instance=request.url.path, headers=exc.headers, **exc.extra
        )

    @app.exception_handler(ParameterError)
    async def _engine_refused(request: Request, exc: ParameterError) -> JSONResponse:
        # The engine names its own fields; the schema that converted the input gave the API location
        # (service.schemas.common.located). An error from outside any schema's conversion is placed
        # under the body by its engine name.
        loc = getattr(exc, API_LOCATION, None) or ["body", *field_path(exc.field)]
        item = field_error(loc, exc.reason)
        element = getattr(exc, "element", None)  # a URDF error names the element at fault
        text = f"{element}: {exc.reason}" if element else exc.reason
        extra = {"element": element} if element else {}
        # the detail names the field as errors[].field does, and as a schema's refusal does
        return problem(422, f"{item['field']}: {text}", instance=request.url.path, errors=[item], **extra)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        items = [_json_invalid(e) or {"loc": list(e.get("loc", [])), "msg": e.get("msg", "")} for e in exc.errors()]
        errors = [_error_item(e) for e in items]
        detail = "; ".join(f"{e['field']}: {e['message']}" for e in errors) or "invalid request"
        return problem(422, detail, instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        if exc.status_code == 400 and "parsing the body" in str(exc.detail):  # e.g. not UTF-8: a body error like any other
            reason = "the body is not valid JSON (UTF-8)"
            cause = exc.__cause__
            if isinstance(cause, ValueError) and not isinstance(cause, UnicodeError) and "digits" in str(cause):
                # Python's guard against quadratic int parsing, not the client's JSON
                reason = f"a number in the body has more than {sys.get_int_max_str_digits()} digits"
            elif isinstance(cause, RecursionError):  # valid JSON, but deeper than Python's parser goes
                reason = "the body's JSON is nested too deeply (arrays or objects inside one another)"
            errors = [field_error(["body"], reason)]
            return problem(422, f"body: {reason}", instance=request.url.path, errors=errors)
        if exc.status_code == 413:
            errors = [field_error(["body"], str(exc.detail))]
            return problem(413, str(exc.detail), instance=request.url.path, headers=exc.headers, errors=errors)
        detail = str(exc.detail)
        if exc.status_code == 404 and detail == TITLES[404]:  # no route matched: say what the paths are
            detail = (
                f"nothing at {request.url.path}: GET /docs lists the API's paths (a stored plan's, job's or "
                "landscape's id is 32 lowercase hexadecimal digits)"
            )
        return problem(exc.status_code, detail, instance=request.url.path, headers=exc.headers)

    def unavailable(request: Request, reason: str, retry_after_s: int) -> JSONResponse:
        return problem(
            503,
            f"{reason}; retry after {retry_after_s} s",
            type_=PROBLEM_BASE + "database-unavailable",
            instance=request.url.path,
            headers={"Retry-After": str(retry_after_s)},
        )

    @app.exception_handler(DBAPIError)
    async def _database_error(request: Request, exc: DBAPIError) -> JSONResponse:
        # never leak the driver message; a locked database is retried before it gets here
        if is_locked(exc):
            return unavailable(request, "the database is busy", RETRY_LOCKED_S)
        reason = request.app.state.db.recover(exc)  # drops pooled connections: recovery without a restart
        if reason is not None:
            return unavailable(request, reason, RETRY_UNAVAILABLE_S)
        if isinstance(exc, DataError) and ("NUL" in str(exc.orig) or "\\u0000" in str(exc.orig)):
            # PostgreSQL refuses text with NUL characters (the schemas refuse them before)
            where = "path" if "\x00" in request.url.path else "query" if "\x00" in str(request.query_params) else "body"
            msg = "text must not contain NUL characters (\\u0000)"
            return problem(422, f"{where}: {msg}", instance=request.url.path, errors=[field_error([where], msg)])
        return problem(500, f"unexpected error: {type(exc).__name__}", instance=request.url.path)

    @app.exception_handler(DatabaseUnavailableError)
    async def _database_missing(request: Request, exc: DatabaseUnavailableError) -> JSONResponse:
        return unavailable(request, exc.reason, RETRY_UNAVAILABLE_S)

    @app.exception_handler(PoolTimeoutError)
    async def _pool_exhausted(request: Request, exc: PoolTimeoutError) -> JSONResponse:
        return unavailable(request, unavailable_reason(exc) or "the database is busy", RETRY_LOCKED_S)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        return problem(500, f"unexpected error: {type(exc).__name__}", instance=request.url.path)


class FieldError(BaseModel):
    field: str = Field(description="dotted path of the offending field, e.g. body.task.q0_deg")
    loc: list[str | int] = Field(
        description="the same path as a list: where (`body`, `query`, `path`, `header`), then names and indices"
    )
    message: str = Field(description="what is wrong with it")


class Problem(BaseModel):
    """RFC 9457 problem details."""

    type: str = Field(description="URI identifying the problem type")
    title: str = Field(description="the HTTP status's reason phrase")
    status: int = Field(description="the HTTP status code")
    detail: str = Field(description="what went wrong, for a person")
    instance: str | None = Field(default=None, description="the request's path")
    errors: list[FieldError] | None = Field(default=None, description="validation errors with field paths (422)")
    available: list[str] | None = Field(
        default=None, description="the media types the resource has (406: `Accept` named none of them)"
    )


def responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries for the given error codes (problem+json, see :func:`service.openapi.install`)."""
    desc = {
        404: "unknown id",
        406: "`Accept` names none of the media types offered (`available` lists them)",
        409: "conflict: the resource's state does not allow it",
        415: "the body's `Content-Type` is not JSON (this resource reads `application/json`)",
        422: "invalid body or parameters",
    }
    return {code: {"description": desc.get(code, TITLES.get(code, "error")), "model": Problem} for code in codes}
