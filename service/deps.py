"""FastAPI dependencies and what the routers share: the database session and settings of the
running app, the route class that gives a handler's session back as soon as the handler returns,
query parameters, admission of heavy work, and image responses."""

from __future__ import annotations

import functools
import hashlib
import inspect
from collections.abc import AsyncIterator, Callable
from typing import Annotated, Any, Literal, TypeVar

import mimeparse
from fastapi import Depends, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.routing import APIRoute
from sqlalchemy.orm import Session
from starlette.convertors import Convertor, register_url_convertor
from typing_extensions import TypeAliasType

from service import figures
from service.errors import MAX_OFFSET, ApiError, NotAcceptableError, UnsupportedMediaTypeError
from service.infra.admission import DEFAULT_COST, Admission
from service.infra.db import Database, elsewhere_if_locked
from service.infra.loop import HandOff
from service.infra.settings import Settings
from service.schemas.common import ID_PATTERN, ID_REGEX
from service.schemas.plans import PLAN_SECTIONS


class IdConvertor(Convertor[str]):
    """``{name:id}`` in a route path: a stored plan's or job's id (32 lowercase hex digits).
    Other text does not match the route (404), so ``/v1/plans/shortest-duration`` is not read as
    a plan id and ``OPTIONS`` lists only the methods of the routes that really match."""

    regex = ID_REGEX

    def convert(self, value: str) -> str:
        return value

    def to_string(self, value: str) -> str:
        return value


register_url_convertor("id", IdConvertor())
PlanId = Annotated[str, Path(pattern=ID_PATTERN, description="a plan's id (32 hex digits)", examples=["0" * 32])]
JobId = Annotated[str, Path(pattern=ID_PATTERN, description="a tuning job's id (32 hex digits)", examples=["0" * 32])]
LandscapeId = Annotated[
    str, Path(pattern=ID_PATTERN, description="an objective landscape's id (32 hex digits)", examples=["0" * 32])
]
RobotId = Annotated[str, Path(description="a stored robot's id (`table1`: the paper's Table-1 robot)", examples=["table1"])]
#: A page of a list: `limit` items after the first `offset`.
Limit = Annotated[int, Query(ge=1, le=500, description="items per page")]
Offset = Annotated[int, Query(ge=0, le=MAX_OFFSET, description="items to skip (the page's start)")]


def get_db(request: Request) -> Database:
    db: Database = request.app.state.db
    return db


async def get_session(request: Request) -> AsyncIterator[Session]:
    """A database session for a blocking handler (a :class:`SessionRoute`'s), made on the event
    loop, where making it does no I/O: the route checks the database file and the handler's first
    query takes a connection, in the handler's thread, which then commits and closes it, so that
    closing it here again does nothing either. A plain generator dependency is entered and left in
    the thread pool: two more trips there and back for every read."""
    db = get_db(request)
    session = db.sessionmaker()
    session.info["database"] = db
    try:
        yield session
    finally:
        session.close()


# The dependencies below are coroutines although they never wait: FastAPI runs a plain function
# dependency in the thread pool, and each trip there and back cost a plan request 0.1-0.3 ms.


async def db_dependency(request: Request) -> Database:
    return get_db(request)


async def get_app_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


SessionDep = Annotated[Session, Depends(get_session)]
DbDep = Annotated[Database, Depends(db_dependency)]
SettingsDep = Annotated[Settings, Depends(get_app_settings)]


def _releasing_sessions(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(endpoint)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        sessions = [value for value in kwargs.values() if isinstance(value, Session)]
        try:
            for session in sessions:
                session.info["database"].check_file()  # a missing file: a 503 before any query
            result = endpoint(*args, **kwargs)
            for session in sessions:
                session.commit()
            return result
        finally:
            for session in sessions:
                session.close()  # rolls back what was not committed (the handler raised)

    return wrapper


class SessionRoute(APIRoute):
    """A route whose (blocking) handler commits and closes its :data:`SessionDep` session in its
    own thread, as it returns (closes it, rolling back, if it raises). FastAPI closes a
    dependency's session only after the response is serialised, and serialising a blocking
    handler's response waits for a thread of the same pool: under load, handlers that have
    returned would hold every database connection while the running ones wait for one (a pool
    timeout, a 503), measured with 50 clients."""

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        if not inspect.iscoroutinefunction(endpoint):
            endpoint = _releasing_sessions(endpoint)
        super().__init__(path, endpoint, **kwargs)


_SECTION = "(" + "|".join(PLAN_SECTIONS) + ")"
#: A comma-separated list of sections (spaces and empty items allowed), or nothing.
SECTIONS_PATTERN = rf"^\s*{_SECTION}?\s*(,\s*{_SECTION}?\s*)*$"
FieldsQuery = Annotated[
    str | None,
    Query(
        max_length=200,
        # In the document only: parse_fields names the unknown sections in its 422.
        json_schema_extra={"pattern": SECTIONS_PATTERN},
        description="comma-separated sections of the plan to return besides its summary (id, method, success, "
        f"message, metrics, ...): any of {', '.join(f'`{name}`' for name in PLAN_SECTIONS)}; default all, "
        "empty for the summary only",
        examples=["replay"],
    ),
]


def schema_ref(model: type) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{model.__name__}"}


def one_of_body(models: tuple[type, ...], examples: dict[str, Any]) -> dict[str, Any]:
    """The ``openapi_extra`` of a route that reads a raw JSON body, one of ``models`` (those FastAPI
    does not see are added to the document's components by :data:`service.openapi.BODY_MODELS`)."""
    schema = {"oneOf": [schema_ref(model) for model in models]}
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": schema, "examples": examples}}}}


T = TypeVar("T")


async def run_admitted(request: Request, work: Callable[[], T], what: str | None = None, cost: float = DEFAULT_COST) -> T:
    """Run ``work()`` once the plan admission lets it in (``what`` names the work in a 503, plans
    by default; ``cost``: its estimated joint-steps, see :mod:`service.infra.admission`): on the
    event loop (:func:`_on_loop_or_pool`) if it costs at most the admission's ``inline_max_cost``
    and the kernels are loaded, else in the thread pool."""
    state = request.app.state
    admission = state.plan_admission
    async with admission.slot(what, cost):
        # not while the kernels load: the loop would wait for numba's compiler lock, /healthz too
        on_loop = cost <= admission.inline_max_cost and state.kernels.state == "ok"
        return await _on_loop_or_pool(admission, state.db, work, on_loop)


async def run_read(request: Request, work: Callable[[], T]) -> T:
    """Run a database read ``work()`` (which opens its own sessions) where cheap plans run: on
    the event loop when the admission runs any there (a SQLite database with a connection to
    spare) and the kernels are loaded, in turns of its own, else in the thread pool. On the loop
    its SQLite sessions do not wait for another writer's lock
    (:func:`~service.infra.db.elsewhere_if_locked`: then the read runs again in the pool);
    ``work`` may hand itself to the pool (:class:`~service.infra.loop.HandOff`) when what it found
    is too large for the loop."""

    def guarded() -> T:
        with elsewhere_if_locked(work):
            return work()

    state = request.app.state
    admission = state.plan_admission
    on_loop = admission.inline_max_cost > 0 and state.kernels.state == "ok"
    return await _on_loop_or_pool(admission, state.db, guarded, on_loop, "reads")


async def _on_loop_or_pool(admission: Admission, db: Database, work: Callable[[], T], on_loop: bool, kind: str = "plans") -> T:
    """``work()`` on the event loop in a turn of ``kind`` (:meth:`~service.infra.admission.Admission.loop_turn`)
    if ``on_loop``, else in the thread pool; work on the loop may hand its rest to the pool
    (:class:`~service.infra.loop.HandOff`: a locked database, a task or a row larger than it said).
    The hand-off to a thread and back cost a paper plan's request, or a read, about a millisecond
    of CPU. (``on_loop`` only once the start-up's rehearsal is over; in its turn, the work still
    goes to the pool if the database pool has no connection free: the loop must not wait for one.)"""
    if on_loop:
        try:
            async with admission.loop_turn(kind):
                if db.spare_connection():
                    return work()
        except HandOff as rest:
            work = rest.then  # run after the except clause: its errors do not carry the HandOff
    return await run_in_threadpool(work)


def negotiate(accept: str | None, offered: list[str]) -> str | None:
    """The media type of ``offered`` that an ``Accept`` header prefers (python-mimeparse: q values,
    wildcards, the most specific range); on a tie the first offered, and the first for a missing,
    empty or malformed header (which RFC 9110 lets a server ignore); None when it accepts none."""
    if accept is None or not accept.strip():
        return offered[0]
    return _best_match(accept, tuple(offered))


@functools.lru_cache(maxsize=256)
def _best_match(accept: str, offered: tuple[str, ...]) -> str | None:
    # kept: clients send the same few headers, and parsing one cost a request 0.02 ms
    try:
        best: str = mimeparse.best_match(offered[::-1], accept)  # it prefers the last of equals
    except mimeparse.MimeTypeParseException:
        return offered[0]
    return best or None


def _refuse_without_json(request: Request, detail: str) -> None:
    accept = request.headers.get("accept")
    if negotiate(accept, ["application/json"]) is None:
        raise NotAcceptableError(f"{accept!r} not available: {detail}", ["application/json"])


async def json_only(request: Request) -> None:
    """A dependency of the JSON-only plan resources: a request whose ``Accept`` excludes JSON
    (``text/csv``, say) is a 406 that points to the trajectory export instead of a JSON answer."""
    plan_id = request.path_params.get("plan_id")
    export = f"/v1/plans/{plan_id}/trajectory" if plan_id else "/v1/plans/{plan_id}/trajectory"
    _refuse_without_json(
        request,
        "plans are application/json; a plan's trajectory is also CSV, MAT, NPZ or a ROS JointTrajectory at "
        f"GET {export} (`Accept` or `?format=csv|mat|npz|json|ros`)",
    )


async def json_answer(request: Request) -> None:
    """A dependency of the other resources that answer JSON only: an ``Accept`` that excludes
    JSON is a 406 before any work."""
    _refuse_without_json(request, "this resource answers application/json")


JsonAnswer = Depends(json_answer)
JsonOnly = Depends(json_only)


async def json_body(request: Request) -> None:
    """A dependency of the resources whose body is JSON: a body sent as another media type
    (``text/plain``, or the form encoding that ``curl -d`` sends without ``-H``), or without a
    ``Content-Type`` (which FastAPI does not read as JSON), is a 415 that says so, not a 422
    calling the JSON "not a valid dictionary". A request without a body goes on to the 422
    that names the missing body."""
    content_type = request.headers.get("content-type")
    if content_type is None:
        if request.headers.get("content-length", "0") == "0" and "transfer-encoding" not in request.headers:
            return
        sent = "a body without Content-Type"
    else:
        main, _, sub = content_type.split(";", 1)[0].strip().lower().partition("/")
        if main == "application" and (sub == "json" or sub.endswith("+json")):
            return
        sent = f"Content-Type {content_type!r} is not JSON"
    raise UnsupportedMediaTypeError(
        f"{sent}: this resource reads application/json (with curl: -H 'content-type: application/json')"
    )


JsonBody = Depends(json_body)

FigureFormat = TypeAliasType("FigureFormat", Literal["svg", "png", "pdf"])
assert set(FigureFormat.__value__.__args__) == set(figures.FORMATS)
Format = Annotated[
    FigureFormat, Query(description="`svg` (default, image/svg+xml), `png` (image/png, at `dpi`) or `pdf` (application/pdf)")
]
#: Resolution of a PNG figure (vector formats ignore it: they are the same at any resolution).
MIN_DPI, MAX_DPI = 50, 600
Dpi = Annotated[
    int | None,
    Query(
        ge=MIN_DPI,
        le=MAX_DPI,
        description=f"dots per inch of a PNG, {MIN_DPI} to {MAX_DPI} (default: the figure's own, "
        f"{figures.DPI}); SVG and PDF ignore it (vector)",
    ),
]


def figure_dpi(fmt: str, dpi: int | None) -> int | None:
    """The resolution a figure is rendered at: ``dpi`` for a PNG, None (the figure's own) otherwise,
    so a vector figure is cached once whatever ``dpi`` was asked."""
    return dpi if fmt == "png" else None


MAX_COMPARE = 8


def figure_name(names: tuple[str, ...] | list[str]) -> Any:
    """A figure name in the path: an enum in the document (so clients type it); an unknown name
    is still answered by the handler, a 404 whose ``valid_names`` lists the names."""
    return Path(description="the figure", json_schema_extra={"enum": list(names)})


#: The image (binary: SVG is text, but clients should store the bytes as they come), and a 304
#: for a conditional request whose ``If-None-Match`` names the current ``ETag``.
IMAGE_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "the figure: SVG (`format=svg`, the default), PNG (`format=png`) or PDF (`format=pdf`)",
        "content": {media: {"schema": {"type": "string", "format": "binary"}} for media in figures.FORMATS.values()},
        "headers": {
            "ETag": {"description": "the figure's version; send it back in `If-None-Match`", "schema": {"type": "string"}},
            "Cache-Control": {
                "description": "`public, max-age=86400` for plan figures (a plan never changes), `no-cache` for a job's",
                "schema": {"type": "string"},
            },
        },
    },
    304: {"description": "not modified: `If-None-Match` names the current `ETag` (weakly compared, in a list or as `*`)"},
}


class UnknownFigureError(ApiError):
    def __init__(self, name: str, valid: tuple[str, ...] | list[str]) -> None:
        super().__init__(
            404,
            f"unknown figure {name!r}; valid names: {', '.join(valid)}",
            type_="https://spacearm.example/problems/unknown-figure",
            valid_names=list(valid),
        )


def _none_match(header: str, etag: str) -> bool:
    """Whether an ``If-None-Match`` header (empty: none) matches ``etag`` (RFC 9110, 13.1.2): ``*``,
    or a comma-separated list of entity tags compared weakly (``W/"x"`` matches ``"x"``: a proxy
    that compresses the answer may weaken the tag it passes on)."""
    if header.strip() == "*":
        return True
    opaque = etag.removeprefix("W/")
    return any(tag.strip().removeprefix("W/") == opaque for tag in header.split(","))


def image_response(request: Request, content: bytes, fmt: str, hit: bool, immutable: bool) -> Response:
    etag = '"' + hashlib.sha1(content).hexdigest() + '"'
    headers = {
        "ETag": etag,
        "X-Figure-Cache": "hit" if hit else "miss",
        "Cache-Control": "public, max-age=86400" if immutable else "no-cache",
    }
    if _none_match(",".join(request.headers.getlist("if-none-match")), etag):  # a list may span lines
        return Response(status_code=304, headers=headers)
    return Response(content, media_type=figures.FORMATS[fmt], headers=headers)
