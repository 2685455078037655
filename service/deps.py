"""FastAPI dependencies: the database session and settings of the running app, and the route
class that gives a handler's session back as soon as the handler returns."""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Iterator
from typing import Annotated, Any, TypeVar

from fastapi import Depends, Path, Query, Request, Response, status
from fastapi.routing import APIRoute
from sqlalchemy import delete
from sqlalchemy.orm import Session
from starlette.convertors import Convertor, register_url_convertor

from service.errors import MAX_OFFSET, NotFoundError
from service.infra.db import Database
from service.infra.settings import Settings
from service.models import Base


class IdConvertor(Convertor[str]):
    """``{name:id}`` in a route path: a stored plan's or job's id (32 lowercase hex digits).
    Other text does not match the route (404), so ``/v1/plans/shortest-duration`` is not read as
    a plan id and ``OPTIONS`` lists only the methods of the routes that really match."""

    regex = "[0-9a-f]{32}"

    def convert(self, value: str) -> str:
        return value

    def to_string(self, value: str) -> str:
        return value


register_url_convertor("id", IdConvertor())
ID_PATTERN = f"^{IdConvertor.regex}$"
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


def get_session(request: Request) -> Iterator[Session]:
    with get_db(request).session() as session:
        yield session


def get_app_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


SessionDep = Annotated[Session, Depends(get_session)]
SettingsDep = Annotated[Settings, Depends(get_app_settings)]


def _releasing_sessions(endpoint: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(endpoint)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        result = endpoint(*args, **kwargs)
        for value in kwargs.values():
            if isinstance(value, Session):
                value.commit()
                value.close()
        return result

    return wrapper


class SessionRoute(APIRoute):
    """A route whose (blocking) handler commits and closes its :data:`SessionDep` session in its
    own thread, as it returns. FastAPI closes a dependency's session only after the response is
    serialised, and serialising a blocking handler's response waits for a thread of the same
    pool: under load, handlers that have returned would hold every database connection while
    the running ones wait for one (a pool timeout, a 503), measured with 50 clients."""

    def __init__(self, path: str, endpoint: Callable[..., Any], **kwargs: Any) -> None:
        if not inspect.iscoroutinefunction(endpoint):
            endpoint = _releasing_sessions(endpoint)
        super().__init__(path, endpoint, **kwargs)


RowT = TypeVar("RowT", bound=Base)


def load_row(session: Session, model: type[RowT], row_id: str, kind: str) -> RowT:
    """The row ``row_id`` of ``model``, or a 404 naming the ``kind`` of thing it is."""
    row = session.get(model, row_id)
    if row is None:
        raise NotFoundError(kind, row_id)
    return row


def delete_row(session: Session, model: type[Base], row_id: str, kind: str) -> Response:
    """Delete the row ``row_id`` of ``model``: 204, or a 404 naming the ``kind``."""
    statement = delete(model).where(model.__table__.c.id == row_id)
    if session.execute(statement).rowcount == 0:  # type: ignore[attr-defined]
        raise NotFoundError(kind, row_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
