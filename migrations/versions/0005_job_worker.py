"""Jobs say which worker ran them: ``tuning_jobs.worker_id`` is the id (``host:pid:random``) of the
worker that claimed the job last. Unlike ``lease_owner``, which is cleared when the job ends, it
stays. Jobs claimed before this revision keep it null.

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-01
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.add_column("tuning_jobs", sa.Column("worker_id", sa.String(128), nullable=True))
    # a job running now is being run by its lease owner
    jobs = sa.table("tuning_jobs", sa.column("worker_id", sa.String), sa.column("lease_owner", sa.String))
    op.execute(jobs.update().where(jobs.c.lease_owner.is_not(None)).values(worker_id=jobs.c.lease_owner))


def downgrade() -> None:
    # ALTER TABLE ... DROP COLUMN (SQLite 3.35+, PostgreSQL), not a batch copy of the table: on SQLite
    # the copy drops the old table, and that deletes the job's generation rows (ON DELETE CASCADE)
    op.execute("ALTER TABLE tuning_jobs DROP COLUMN worker_id")
