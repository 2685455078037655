"""The schema comes from Alembic: upgrade from empty to head, down to base and up again."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from sqlalchemy import inspect, text

from service.db import make_engine
from service.migrate import current_revision, downgrade, head_revision, upgrade

ROOT = Path(__file__).resolve().parents[2]
TABLES = {"robots", "plans", "tuning_jobs"}


def test_upgrade_downgrade_roundtrip(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'sub' / 'm.db'}"
    upgrade(url)
    engine = make_engine(url)
    try:
        assert set(inspect(engine).get_table_names()) >= TABLES
        assert current_revision(engine) == head_revision(url) == "0001"
        columns = {c["name"] for c in inspect(engine).get_columns("tuning_jobs")}
        assert {"status", "lease_owner", "lease_expires_at", "attempts", "progress", "result", "idempotency_key"} <= columns
        with engine.connect() as conn:
            assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"
            assert conn.execute(text("PRAGMA busy_timeout")).scalar() > 0
        engine.dispose()
        downgrade(url)
        assert not TABLES & set(inspect(engine).get_table_names())
        assert current_revision(engine) is None
        upgrade(url)
        assert set(inspect(engine).get_table_names()) >= TABLES
    finally:
        engine.dispose()


def test_cli_migrate_seeds_preset_and_alembic_ini_works(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'cli.db'}"
    env = {"SPACEARM_DATABASE_URL": url, "PATH": "/usr/bin:/bin"}
    subprocess.run([sys.executable, "-m", "service", "migrate"], cwd=ROOT, env=env, check=True, capture_output=True)
    engine = make_engine(url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT preset FROM robots WHERE id = 'table1'")).scalar() == 1
    engine.dispose()
    # the repository's alembic.ini drives the same migrations
    out = subprocess.run(
        [sys.executable, "-m", "alembic", "-c", str(ROOT / "alembic.ini"), "current"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "0001" in out.stdout
