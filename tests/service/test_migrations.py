"""The schema comes from Alembic: upgrade from empty to head, down to base and up again; the
data migration of 0002 both ways; migrations are atomic (a migrate killed at random moments
leaves a database that the next migrate brings to exactly the clean schema); half-migrated
legacy databases are repaired or refused with a message."""

from __future__ import annotations

import json
import os
import random
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import inspect, text

from service.infra.db import make_engine
from service.infra.migrate import MigrationError, current_revision, downgrade, head_revision, upgrade
from service.infra.revision import HEAD
from service.infra.storage import unpack_trajectory

ROOT = Path(__file__).resolve().parents[2]
TABLES = {"robots", "plans", "tuning_jobs", "tuning_job_generations", "web_sessions", "service_probes", "landscapes"}


def _schema(path: Path) -> list[tuple[str, ...]]:
    with sqlite3.connect(path) as con:
        rows = con.execute("SELECT type, name, tbl_name, sql FROM sqlite_master WHERE name NOT LIKE 'sqlite_%' ORDER BY name")
        return [tuple(str(v) for v in row) for row in rows]


def test_upgrade_downgrade_roundtrip(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'sub' / 'm.db'}"
    upgrade(url)
    engine = make_engine(url)
    try:
        assert set(inspect(engine).get_table_names()) >= TABLES
        assert current_revision(engine) == head_revision(url) == "0007" == HEAD  # /readyz's head, without Alembic
        columns = {c["name"] for c in inspect(engine).get_columns("tuning_jobs")}
        assert {"status", "lease_owner", "lease_expires_at", "attempts", "progress", "result", "idempotency_key"} <= columns
        assert "idempotency_fingerprint" in columns
        assert {c["name"] for c in inspect(engine).get_columns("plans")} >= {"trajectory_data"}
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


def test_0002_converts_stored_trajectories_both_ways(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'data.db'}"
    upgrade(url, "0001")
    trajectory = {
        "t_s": [0.0, 0.25, 0.5],
        "det_gjm": [None, 1.5, -2.0],
        "joint_angles_deg": [[1.0, None], [2.0, 3.0], [4.0, 5.0]],
    }
    with sqlite3.connect(tmp_path / "data.db") as con:
        con.execute("INSERT INTO robots (id, name, parameters, preset, created_at) VALUES ('r', 'r', '{}', 0, '2026-01-01')")
        con.execute(
            "INSERT INTO plans (id, robot_id, request, method, success, message, metrics, trajectory, replay, elapsed_s, "
            "created_at) VALUES ('p', 'r', '{}', '{}', 1, 'ok', '{}', ?, NULL, 0.1, '2026-01-01')",
            (json.dumps(trajectory),),
        )
    upgrade(url)
    with sqlite3.connect(tmp_path / "data.db") as con:
        (blob,) = con.execute("SELECT trajectory_data FROM plans WHERE id = 'p'").fetchone()
    arrays = unpack_trajectory(blob)
    np.testing.assert_array_equal(arrays["t_s"], [0.0, 0.25, 0.5])
    np.testing.assert_array_equal(arrays["det_gjm"], [np.nan, 1.5, -2.0])
    np.testing.assert_array_equal(arrays["joint_angles_deg"], [[1.0, np.nan], [2.0, 3.0], [4.0, 5.0]])
    downgrade(url, "0001")
    with sqlite3.connect(tmp_path / "data.db") as con:
        (stored,) = con.execute("SELECT trajectory FROM plans WHERE id = 'p'").fetchone()
    assert json.loads(stored) == trajectory


def test_0004_moves_job_history_into_rows_and_back(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'jobs.db'}"
    upgrade(url, "0003")
    history = [
        {"phase": "adaptive", "role": "tuned", "generation": 0, "best": 0.003, "mean": 0.01, "feasible": 5},
        {"phase": "adaptive", "role": "tuned", "generation": 1, "best": 0.002, "mean": None, "feasible": 0},
        {"phase": "dls", "generation": 0, "best": 0.004, "mean": 0.02, "feasible": 3},  # an old row without a role
    ]
    progress = {"generation": 1, "generations": 2, "evaluations": 12, "attempt": 2, "history": history}
    with sqlite3.connect(tmp_path / "jobs.db") as con:
        con.execute(
            "INSERT INTO tuning_jobs (id, status, request, progress, attempts, max_attempts, cancel_requested, created_at, "
            "updated_at) VALUES ('j', 'running', ?, ?, 2, 3, 0, '2026-01-01', '2026-01-01')",
            (json.dumps({"method": "adaptive", "ga": {"generations": 1}}), json.dumps(progress)),
        )
    upgrade(url)
    with sqlite3.connect(tmp_path / "jobs.db") as con:
        rows = con.execute(
            "SELECT attempt, seq, phase, role, generation, best, mean, feasible FROM tuning_job_generations ORDER BY seq"
        ).fetchall()
        (stored,) = con.execute("SELECT progress FROM tuning_jobs WHERE id = 'j'").fetchone()
    assert rows == [
        (2, 1, "adaptive", "tuned", 0, 0.003, 0.01, 5),
        (2, 2, "adaptive", "tuned", 1, 0.002, None, 0),
        (2, 3, "dls", "dls_baseline", 0, 0.004, 0.02, 3),
    ]
    summary = json.loads(stored)
    assert "history" not in summary and summary["records"] == 3 and summary["evaluations"] == 12
    downgrade(url, "0003")
    with sqlite3.connect(tmp_path / "jobs.db") as con:
        (stored,) = con.execute("SELECT progress FROM tuning_jobs WHERE id = 'j'").fetchone()
    back = json.loads(stored)["history"]
    assert [r["role"] for r in back] == ["tuned", "tuned", "dls_baseline"]
    assert [(r["generation"], r["best"], r["mean"], r["feasible"]) for r in back] == [
        (h["generation"], h["best"], h["mean"], h["feasible"]) for h in history
    ]


def test_migrate_killed_at_random_moments_never_leaves_a_broken_database(tmp_path: Path) -> None:
    """30 kills: mostly in the window where the DDL runs (just after the file appears), some at
    any moment of the process. Each time, the next migrate succeeds and the schema is exactly
    the clean one."""
    clean = tmp_path / "clean.db"
    upgrade(f"sqlite:///{clean}")
    expected = _schema(clean)
    rng = random.Random(20261122)
    outcomes = {"killed before the file": 0, "killed during or after the DDL": 0, "finished": 0}
    for trial in range(30):
        path = tmp_path / f"kill{trial}.db"
        url = f"sqlite:///{path}"
        env = {**os.environ, "SPACEARM_DATABASE_URL": url}
        proc = subprocess.Popen(
            [sys.executable, "-m", "service", "migrate"], cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        start = time.monotonic()
        if trial % 5 == 4:
            time.sleep(rng.uniform(0.0, 1.2))  # anywhere in the process's life
        else:
            while not path.exists() and proc.poll() is None and time.monotonic() - start < 30:
                time.sleep(0.0005)
            time.sleep(rng.uniform(0.0, 0.15))  # in the DDL window
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            outcomes["killed during or after the DDL" if path.exists() else "killed before the file"] += 1
        else:
            outcomes["finished"] += 1
        proc.wait(30)
        # all or nothing: the old schema (none) or the new one, never a part of it
        left = _schema(path) if path.exists() else []
        assert left in ([], expected), f"trial {trial}: the kill left {len(left)} schema objects"
        upgrade(url)  # must succeed whatever state the kill left
        assert _schema(path) == expected, f"trial {trial}"
        with sqlite3.connect(path) as con:
            assert con.execute("SELECT version_num FROM alembic_version").fetchall() == [("0007",)]
    assert outcomes["killed during or after the DDL"] >= 15, outcomes


def test_0005_keeps_the_worker_of_a_running_job_and_drops_the_column_on_downgrade(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'workers.db'}"
    upgrade(url, "0004")
    with sqlite3.connect(tmp_path / "workers.db") as con:
        for job_id, status, owner in (("r", "running", "host:1:ab"), ("q", "queued", None)):
            con.execute(
                "INSERT INTO tuning_jobs (id, status, request, attempts, max_attempts, cancel_requested, lease_owner, "
                "created_at, updated_at) VALUES (?, ?, '{}', 1, 3, 0, ?, '2026-01-01', '2026-01-01')",
                (job_id, status, owner),
            )
        con.execute("INSERT INTO tuning_job_generations VALUES ('r', 1, 1, 'adaptive', 'tuned', 0, 0.1, 0.2, 3, '2026-01-01')")
    upgrade(url)
    with sqlite3.connect(tmp_path / "workers.db") as con:
        assert dict(con.execute("SELECT id, worker_id FROM tuning_jobs").fetchall()) == {"r": "host:1:ab", "q": None}
    downgrade(url, "0004")
    with sqlite3.connect(tmp_path / "workers.db") as con:
        assert "worker_id" not in {row[1] for row in con.execute("PRAGMA table_info(tuning_jobs)")}
        assert con.execute("SELECT count(*) FROM tuning_jobs").fetchone() == (2,)
        # the column is dropped in place: a copy of the table would cascade-delete the generation rows
        assert con.execute("SELECT count(*) FROM tuning_job_generations").fetchone() == (1,)


def test_half_migrated_legacy_database_is_repaired_or_refused(tmp_path: Path) -> None:
    """What the earlier, non-transactional migrate could leave: tables but no version."""
    empty = tmp_path / "half.db"
    with sqlite3.connect(empty) as con:
        con.execute("CREATE TABLE robots (id VARCHAR(64) PRIMARY KEY, name VARCHAR(200) NOT NULL)")
    upgrade(f"sqlite:///{empty}")  # spacearm's table, empty: dropped and created again
    assert "parameters" in {row[1] for row in sqlite3.connect(empty).execute("PRAGMA table_info(robots)")}

    holding = tmp_path / "holding.db"
    with sqlite3.connect(holding) as con:
        con.execute("CREATE TABLE robots (id VARCHAR(64) PRIMARY KEY, name VARCHAR(200) NOT NULL)")
        con.execute("INSERT INTO robots VALUES ('mine', 'precious')")
    with pytest.raises(MigrationError, match=r"holding data \(robots \(1 rows\)\).*alembic -c alembic.ini stamp"):
        upgrade(f"sqlite:///{holding}")
    assert sqlite3.connect(holding).execute("SELECT name FROM robots").fetchall() == [("precious",)]  # untouched

    foreign = tmp_path / "foreign.db"
    with sqlite3.connect(foreign) as con:
        con.execute("CREATE TABLE invoices (id INTEGER)")
    with pytest.raises(MigrationError, match="not spacearm's"):
        upgrade(f"sqlite:///{foreign}")
    out = subprocess.run(
        [sys.executable, "-m", "service", "migrate"],
        cwd=ROOT,
        env={**os.environ, "SPACEARM_DATABASE_URL": f"sqlite:///{foreign}"},
        capture_output=True,
        text=True,
    )
    assert out.returncode == 1 and "spacearm migrate: the database has tables that are not spacearm's (invoices)" in out.stderr


def _migrate_imports(env: dict[str, str]) -> set[str]:
    """The top-level packages a ``spacearm migrate`` process imported (``-X importtime``)."""
    command = [sys.executable, "-X", "importtime", "-m", "service", "migrate"]
    out = subprocess.run(command, cwd=ROOT, env=env, check=True, capture_output=True, text=True)
    return {line.rsplit("|", 1)[1].strip().split(".")[0] for line in out.stderr.splitlines() if line.startswith("import time:")}


def test_cli_migrate_seeds_preset_and_alembic_ini_works(tmp_path: Path) -> None:
    from service.infra.revision import PRESET_ROBOT_IDS
    from service.usecases.robots import preset_robots

    assert list(PRESET_ROBOT_IDS) == list(preset_robots())
    url = f"sqlite:///{tmp_path / 'cli.db'}"
    env = {"SPACEARM_DATABASE_URL": url, "PATH": "/usr/bin:/bin"}
    # A new database: every preset, built with the engine (the URDF presets with their parser) ...
    assert {"engine", "yourdfpy"} <= _migrate_imports(env)
    engine = make_engine(url)
    with engine.connect() as conn:
        assert conn.execute(text("SELECT preset FROM robots WHERE id = 'table1'")).scalar() == 1
        assert sorted(conn.execute(text("SELECT id FROM robots WHERE preset")).scalars()) == sorted(PRESET_ROBOT_IDS)
    # ... and one that has them: no engine (``spacearm run`` migrates at every start, beside the
    # API's and the workers' imports)
    assert not {"engine", "numba", "yourdfpy"} & _migrate_imports(env)
    with engine.connect() as conn:
        conn.execute(text("DELETE FROM robots WHERE id = 'table1'"))
        conn.commit()
    imported = _migrate_imports(env)
    assert "engine" in imported and "yourdfpy" not in imported  # only the missing preset is built
    with engine.connect() as conn:
        conn.execute(text("DELETE FROM robots WHERE id = 'arm3'"))
        conn.commit()
    assert {"engine", "yourdfpy"} <= _migrate_imports(env)
    with engine.connect() as conn:
        assert sorted(conn.execute(text("SELECT id FROM robots WHERE preset")).scalars()) == sorted(PRESET_ROBOT_IDS)
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
    assert "0007" in out.stdout
