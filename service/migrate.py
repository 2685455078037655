"""Alembic helpers: upgrade/downgrade, the current and head revisions, and the presets."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, select
from sqlalchemy.exc import IntegrityError

import migrations
from engine import RobotModel, table1_robot, urdf_robot
from engine.model import URDF_PRESETS
from service.db import Database, ensure_sqlite_dir
from service.models import Robot

PRESET_ROBOT_ID = "table1"


#: The robots every database starts with: the paper's Table-1 robot and the URDF examples (a
#: 7-joint arm on a spacecraft, a 3-joint arm), built only when missing (reading a URDF imports
#: its parser, about a second).
PRESET_ROBOTS: dict[str, Callable[[], RobotModel]] = {
    PRESET_ROBOT_ID: table1_robot,
    **{name: functools.partial(urdf_robot, name) for name in URDF_PRESETS},
}


def alembic_config(url: str) -> Config:
    config = Config()
    config.set_main_option("script_location", str(Path(migrations.__file__).parent))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def upgrade(url: str, revision: str = "head") -> None:
    ensure_sqlite_dir(url)
    command.upgrade(alembic_config(url), revision)


def downgrade(url: str, revision: str = "base") -> None:
    command.downgrade(alembic_config(url), revision)


def head_revision(url: str) -> str | None:
    return ScriptDirectory.from_config(alembic_config(url)).get_current_head()


def current_revision(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def seed_presets(db: Database) -> None:
    """Insert the preset robots that are missing (idempotent)."""
    for robot_id, build in PRESET_ROBOTS.items():
        try:
            with db.session() as session:
                if session.scalar(select(Robot.id).where(Robot.id == robot_id)) is None:
                    model = build()
                    session.add(Robot(id=robot_id, name=model.name, parameters=model.to_dict(), preset=True))
        except IntegrityError:  # another process seeded it at the same time
            pass
