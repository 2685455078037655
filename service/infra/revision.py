"""The schema revision the code expects and the one a database is at, without Alembic: the API
checks them on every ``/readyz``, and importing Alembic (its operations and dialects) would cost
every API process about 16 MiB. ``tests/service/test_migrations.py`` checks :data:`HEAD` against
Alembic's head of ``migrations/``, so a new migration that forgets to update it fails there.

Also which preset robots a database lacks, without the engine: ``spacearm migrate`` imports the
engine (and, for the URDF presets, the URDF parser) only when one is missing."""

from __future__ import annotations

from sqlalchemy import Engine, column, inspect, select, table, text

#: The head revision of ``migrations/versions`` (what ``spacearm migrate`` upgrades to).
HEAD = "0007"
#: Alembic's table recording a database's revision.
VERSION_TABLE = "alembic_version"
#: The preset robots every database holds (the keys of :func:`service.usecases.robots.preset_robots`,
#: which ``tests/service/test_migrations.py`` checks), seeded by :func:`service.usecases.robots.seed_presets`.
PRESET_ROBOT_IDS = ("table1", "table1-geometry", "arm7", "arm3")
_ROBOT_ID = table("robots", column("id")).c.id  # without service.models: this module is read alone


def current_revision(engine: Engine) -> str | None:
    """The revision ``engine``'s database is at, or None if it was never migrated."""
    with engine.connect() as conn:
        if not inspect(conn).has_table(VERSION_TABLE):
            return None
        rows = conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).scalars().all()
    return rows[0] if len(rows) == 1 else None


def missing_presets(engine: Engine) -> list[str]:
    """The preset robots (:data:`PRESET_ROBOT_IDS`) that ``engine``'s database lacks, in order."""
    with engine.connect() as conn:
        present = set(conn.execute(select(_ROBOT_ID).where(_ROBOT_ID.in_(PRESET_ROBOT_IDS))).scalars())
    return [robot_id for robot_id in PRESET_ROBOT_IDS if robot_id not in present]
