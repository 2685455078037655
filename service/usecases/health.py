"""Readiness of the database: reachable, at the head revision, taking writes."""

from __future__ import annotations

import os
import socket
from typing import Any

from sqlalchemy.dialects import postgresql, sqlite

from service.infra.db import Database, unavailable_reason
from service.infra.revision import HEAD, current_revision
from service.models import ServiceProbe, utcnow
from service.schemas.health import Health

PROBE_NAME = f"readyz:{socket.gethostname()}:{os.getpid()}"[:64]


def _write_probe(db: Database) -> None:
    """Rewrite this process's row of ``service_probes``: the database takes writes."""
    values: dict[str, Any] = {"name": PROBE_NAME, "updated_at": utcnow()}
    with db.session() as session:
        dialect = session.get_bind().dialect.name
        insert = (postgresql if dialect == "postgresql" else sqlite).insert(ServiceProbe).values(**values)
        session.execute(insert.on_conflict_do_update(index_elements=["name"], set_={"updated_at": values["updated_at"]}))


def check_database(health_db: Database, db: Database) -> Health:
    """Reachable, at the head revision, taking writes, and (SQLite) the file at its path is the
    file the service holds."""
    head = HEAD
    try:
        db.check_file()  # reconnects the API's pool if the file was replaced
        health_db.check_file()
        revision = current_revision(health_db.engine)
        if revision != head:
            return Health(status="unavailable", kernels="ok", database="not migrated", revision=revision, head=head)
        _write_probe(health_db)
    except Exception as exc:
        reason = health_db.recover(exc) or unavailable_reason(exc) or f"unreachable: {type(exc).__name__}"
        db.recover(exc)
        return Health(status="unavailable", kernels="ok", database=reason, head=head)
    return Health(status="ok", kernels="ok", database="ok", revision=revision, head=head)
