"""A tuning job's history as rows: ``tuning_job_generations`` gets one row per finished
generation (appended, never rewritten); the history that ``tuning_jobs.progress`` carried is
moved into it, and the progress keeps only its summary.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25
"""

from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JOBS = sa.table(
    "tuning_jobs",
    sa.column("id", sa.String),
    sa.column("request", sa.JSON),
    sa.column("progress", sa.JSON),
    sa.column("attempts", sa.Integer),
)
ROWS = sa.table(
    "tuning_job_generations",
    sa.column("job_id", sa.String),
    sa.column("attempt", sa.Integer),
    sa.column("seq", sa.Integer),
    sa.column("phase", sa.String),
    sa.column("role", sa.String),
    sa.column("generation", sa.Integer),
    sa.column("best", sa.Float),
    sa.column("mean", sa.Float),
    sa.column("feasible", sa.Integer),
    sa.column("created_at", sa.DateTime),
)


def _role(row: dict[str, Any], method: str, restarts: int) -> str:
    """Rows of workers older than roles go by name (and, when the tuned method is DLS itself, by
    the restart of the generations at 0)."""
    if "role" in row:
        return str(row["role"])
    if row.get("phase") == "dls" and (method != "dls" or restarts > 1):
        return "dls_baseline"
    return "tuned"


def upgrade() -> None:
    op.create_table(
        "tuning_job_generations",
        sa.Column("job_id", sa.String(64), sa.ForeignKey("tuning_jobs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("attempt", sa.Integer(), primary_key=True),
        sa.Column("seq", sa.Integer(), primary_key=True),
        sa.Column("phase", sa.String(16), nullable=False),
        sa.Column("role", sa.String(16), nullable=False),
        sa.Column("generation", sa.Integer(), nullable=False),
        sa.Column("best", sa.Float(), nullable=True),
        sa.Column("mean", sa.Float(), nullable=True),
        sa.Column("feasible", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
    )
    conn = op.get_bind()
    for job_id, request, progress, attempts in conn.execute(
        sa.select(JOBS.c.id, JOBS.c.request, JOBS.c.progress, JOBS.c.attempts)
    ).all():
        progress = dict(progress or {})
        history = progress.pop("history", None) or []
        if not history:
            continue
        method = str((request or {}).get("method", "adaptive"))
        attempt = int(progress.get("attempt", attempts or 0))
        restarts = 0
        rows = []
        for seq, row in enumerate(history, start=1):
            restarts += row.get("generation") == 0
            rows.append(
                {
                    "job_id": job_id,
                    "attempt": attempt,
                    "seq": seq,
                    "phase": str(row.get("phase") or method),
                    "role": _role(row, method, restarts),
                    "generation": int(row.get("generation", 0)),
                    "best": row.get("best"),
                    "mean": row.get("mean"),
                    "feasible": int(row.get("feasible", 0)),
                    "created_at": sa.func.current_timestamp(),
                }
            )
        for row in rows:
            conn.execute(ROWS.insert().values(**row))
        progress["attempt"] = attempt
        progress["records"] = len(rows)
        conn.execute(JOBS.update().where(JOBS.c.id == job_id).values(progress=progress))


def downgrade() -> None:
    conn = op.get_bind()
    for (job_id,) in conn.execute(sa.select(JOBS.c.id)).all():
        rows = conn.execute(sa.select(ROWS).where(ROWS.c.job_id == job_id).order_by(ROWS.c.attempt.desc(), ROWS.c.seq)).all()
        if not rows:
            continue
        attempt = rows[0].attempt
        history = [
            {k: getattr(r, k) for k in ("phase", "role", "generation", "best", "mean", "feasible")}
            for r in rows
            if r.attempt == attempt
        ]
        progress = dict(conn.execute(sa.select(JOBS.c.progress).where(JOBS.c.id == job_id)).scalar() or {})
        progress["history"] = history
        progress.pop("records", None)
        conn.execute(JOBS.update().where(JOBS.c.id == job_id).values(progress=progress))
    op.drop_table("tuning_job_generations")
