"""Reliability: trajectories stored as compressed arrays, idempotency fingerprints, revocable
web sessions, and a row the readiness probe writes.

- ``plans.trajectory`` (JSON text) becomes ``plans.trajectory_data``: the arrays as a compressed
  ``.npz`` (about a third of the size); existing rows are converted in the migration.
- ``tuning_jobs.idempotency_fingerprint``: SHA-256 of the request body stored with its key, so a
  key reused with another body is refused.
- ``web_sessions``: sign-in sessions of the web pages (the cookie holds a random id whose hash is
  stored here; signing out deletes the row).
- ``service_probes``: one row per probe name, rewritten by ``/readyz`` to prove the database
  takes writes.

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

from service.infra.storage import pack_trajectory, unpack_trajectory

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

plans = sa.table(
    "plans",
    sa.column("id", sa.String(64)),
    sa.column("trajectory", sa.JSON()),
    sa.column("trajectory_data", sa.LargeBinary()),
)


def upgrade() -> None:
    with op.batch_alter_table("plans") as batch:
        batch.add_column(sa.Column("trajectory_data", sa.LargeBinary(), nullable=True))
    bind = op.get_bind()
    for plan_id, trajectory in bind.execute(sa.select(plans.c.id, plans.c.trajectory)).all():
        bind.execute(plans.update().where(plans.c.id == plan_id).values(trajectory_data=pack_trajectory(trajectory)))
    with op.batch_alter_table("plans") as batch:
        batch.drop_column("trajectory")
        batch.alter_column("trajectory_data", existing_type=sa.LargeBinary(), nullable=False)
    with op.batch_alter_table("tuning_jobs") as batch:
        batch.add_column(sa.Column("idempotency_fingerprint", sa.String(64), nullable=True))
    op.create_table(
        "web_sessions",
        sa.Column("id", sa.String(64), primary_key=True),
        sa.Column("key_digest", sa.String(64), nullable=False),
        sa.Column("csrf_token", sa.String(64), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.Column("expires_at", sa.DateTime(), nullable=False),
    )
    op.create_table(
        "service_probes",
        sa.Column("name", sa.String(64), primary_key=True),
        sa.Column("updated_at", sa.DateTime(), nullable=False),
    )


def downgrade() -> None:
    op.drop_table("service_probes")
    op.drop_table("web_sessions")
    with op.batch_alter_table("tuning_jobs") as batch:
        batch.drop_column("idempotency_fingerprint")
    with op.batch_alter_table("plans") as batch:
        batch.add_column(sa.Column("trajectory", sa.JSON(), nullable=True))
    bind = op.get_bind()
    for plan_id, data in bind.execute(sa.select(plans.c.id, plans.c.trajectory_data)).all():
        # the engine's JSON serializer writes the arrays, NaN as null
        bind.execute(plans.update().where(plans.c.id == plan_id).values(trajectory=unpack_trajectory(data)))
    with op.batch_alter_table("plans") as batch:
        batch.drop_column("trajectory_data")
        batch.alter_column("trajectory", existing_type=sa.JSON(), nullable=False)
