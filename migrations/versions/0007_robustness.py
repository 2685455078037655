"""Mass-property uncertainty (issue 20): a plan's robustness, and the stage (GA or refinement)
of a tuning job's history record.

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-27
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("plans") as batch:
        batch.add_column(sa.Column("robustness", sa.JSON(), nullable=True))
    with op.batch_alter_table("tuning_job_generations") as batch:
        batch.add_column(sa.Column("stage", sa.String(16), nullable=False, server_default="ga"))


def downgrade() -> None:
    with op.batch_alter_table("tuning_job_generations") as batch:
        batch.drop_column("stage")
    with op.batch_alter_table("plans") as batch:
        batch.drop_column("robustness")
