"""The schema revision the code expects and the one a database is at, without Alembic: the API
checks them on every ``/readyz``, and importing Alembic (its operations and dialects) would cost
every API process about 16 MiB. ``tests/service/test_migrations.py`` checks :data:`HEAD` against
Alembic's head of ``migrations/``, so a new migration that forgets to update it fails there."""

from __future__ import annotations

from sqlalchemy import Engine, inspect, text

#: The head revision of ``migrations/versions`` (what ``spacearm migrate`` upgrades to).
HEAD = "0007"
#: Alembic's table recording a database's revision.
VERSION_TABLE = "alembic_version"


def current_revision(engine: Engine) -> str | None:
    """The revision ``engine``'s database is at, or None if it was never migrated."""
    with engine.connect() as conn:
        if not inspect(conn).has_table(VERSION_TABLE):
            return None
        rows = conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).scalars().all()
    return rows[0] if len(rows) == 1 else None
