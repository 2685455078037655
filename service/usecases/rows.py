"""Loading and deleting a stored row by its id, a 404 naming what it is when there is none."""

from __future__ import annotations

from typing import TypeVar

from sqlalchemy import delete as sql_delete
from sqlalchemy.orm import Session

from service.errors import NotFoundError
from service.infra.db import Database
from service.models import Base

RowT = TypeVar("RowT", bound=Base)


def load(session: Session, model: type[RowT], row_id: str, kind: str) -> RowT:
    """The row ``row_id`` of ``model``, or a 404 naming the ``kind`` of thing it is."""
    row = session.get(model, row_id)
    if row is None:
        raise NotFoundError(kind, row_id)
    return row


def delete(db: Database, model: type[Base], row_id: str, kind: str) -> None:
    """Delete the row ``row_id`` of ``model`` in a transaction of its own (also on a full disk:
    :meth:`Database.freeing`), or a 404 naming the ``kind``."""
    statement = sql_delete(model).where(model.__table__.c.id == row_id)

    def remove(session: Session) -> None:
        if session.execute(statement).rowcount == 0:  # type: ignore[attr-defined]
            raise NotFoundError(kind, row_id)

    db.freeing(lambda: db.write(remove))
