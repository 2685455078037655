"""Alembic environment: the URL comes from the Alembic config (set by ``spacearm migrate``) or
from ``SPACEARM_DATABASE_URL``. All pending migrations run in one transaction with their version
stamp (SQLite: ``BEGIN IMMEDIATE`` on an engine whose DDL is transactional; PostgreSQL:
transactional DDL and an advisory lock), so a migration killed at any moment leaves the old
schema or the new one, and two migrations started at once run one after the other."""

from __future__ import annotations

from alembic import context
from sqlalchemy import text

from service.infra.db import make_engine
from service.infra.settings import Settings
from service.models import Base

config = context.config
target_metadata = Base.metadata
MIGRATION_LOCK = 8_150_211  # pg_advisory_xact_lock key of `spacearm migrate`


def _url() -> str:
    return config.get_main_option("sqlalchemy.url") or Settings().database_url


def run_migrations_offline() -> None:
    context.configure(url=_url(), target_metadata=target_metadata, literal_binds=True, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def _run(conn: object) -> None:
    context.configure(connection=conn, target_metadata=target_metadata, render_as_batch=True, transactional_ddl=True)
    with context.begin_transaction():
        if conn.dialect.name == "postgresql":  # type: ignore[attr-defined]
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK})  # type: ignore[attr-defined]
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    engine = make_engine(_url(), create=True)
    try:
        with engine.connect() as conn:
            _run(conn)
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
