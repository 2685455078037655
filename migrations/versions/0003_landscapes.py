"""Objective landscapes: ``landscapes`` holds each computed grid (B, feasibility and peak joint
speed per cell as a compressed ``.npz``, see ``service.infra.storage``) with its request and summary.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-22
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "landscapes",
        sa.Column("id", sa.String(64), primary_key=True),
        sa.Column("robot_id", sa.String(64), sa.ForeignKey("robots.id", ondelete="SET NULL"), nullable=True),
        sa.Column("request", sa.JSON(), nullable=False),
        sa.Column("summary", sa.JSON(), nullable=False),
        sa.Column("grids", sa.LargeBinary(), nullable=False),
        sa.Column("elapsed_s", sa.Float(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
    )
    op.create_index("ix_landscapes_created_at", "landscapes", ["created_at"])


def downgrade() -> None:
    op.drop_index("ix_landscapes_created_at", table_name="landscapes")
    op.drop_table("landscapes")
