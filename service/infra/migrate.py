"""Alembic helpers: upgrade (with a check of half-done databases), downgrade, the current and
head revisions (the preset robots are seeded by :func:`service.usecases.robots.seed_presets`).

Migrations are atomic (see ``migrations/env.py``). A database left half-migrated by an earlier,
non-transactional version of ``spacearm migrate`` (tables but no ``alembic_version``) is
repaired when its tables are spacearm's and empty (they are dropped and created again);
otherwise :func:`upgrade` refuses with :class:`MigrationError`, saying what to do.
"""

from __future__ import annotations

import logging
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.script import ScriptDirectory
from sqlalchemy import func, inspect, select, table, text

import migrations
from service.infra.db import ensure_sqlite_dir, make_engine
from service.infra.revision import current_revision
from service.models import Base

__all__ = ["MigrationError", "current_revision", "downgrade", "head_revision", "upgrade"]

log = logging.getLogger("spacearm.migrate")


class MigrationError(Exception):
    """The database is in a state ``spacearm migrate`` will not touch; the message says why and
    what to do."""


def alembic_config(url: str) -> Config:
    config = Config()
    config.set_main_option("script_location", str(Path(migrations.__file__).parent))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def _check_half_done(url: str) -> None:
    """Repair or refuse a database with spacearm tables but no migration record."""
    engine = make_engine(url, create=True)
    try:
        with engine.begin() as conn:
            names = set(inspect(conn).get_table_names())
            if not names or ("alembic_version" in names and conn.execute(text("SELECT count(*) FROM alembic_version")).scalar()):
                return
            ours = {t.name for t in Base.metadata.sorted_tables}
            foreign = names - ours - {"alembic_version"}
            if foreign:
                raise MigrationError(
                    f"the database has tables that are not spacearm's ({', '.join(sorted(foreign))}) and no migration "
                    "record: point SPACEARM_DATABASE_URL at an empty or spacearm database"
                )
            present = sorted(names & ours)
            rows = {name: conn.execute(select(func.count()).select_from(table(name))).scalar() for name in present}
            if any(rows.values()):
                held = ", ".join(f"{name} ({n} rows)" for name, n in rows.items() if n)
                raise MigrationError(
                    f"the database has spacearm tables holding data ({held}) but no migration record, so its "
                    "schema revision is unknown: restore it from a backup, or, if you know the revision its tables "
                    "match, record it with `alembic -c alembic.ini stamp <revision>` and run `spacearm migrate` again"
                )
            log.warning("repairing a half-migrated database: dropping its empty tables %s", ", ".join(present))
            for name in reversed([t.name for t in Base.metadata.sorted_tables]):
                if name in names:
                    conn.execute(text(f'DROP TABLE "{name}"'))
            if "alembic_version" in names:
                conn.execute(text("DROP TABLE alembic_version"))
    finally:
        engine.dispose()


def upgrade(url: str, revision: str = "head") -> None:
    ensure_sqlite_dir(url)
    _check_half_done(url)
    command.upgrade(alembic_config(url), revision)


def downgrade(url: str, revision: str = "base") -> None:
    command.downgrade(alembic_config(url), revision)


def head_revision(url: str) -> str | None:
    return ScriptDirectory.from_config(alembic_config(url)).get_current_head()
