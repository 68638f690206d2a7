"""tenants: every job, token and uploaded asset belongs to one; idempotency keys are per tenant

Revision ID: 0002
Revises: 0001
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Tokens of 0001 were all configured ones, which every start stores again: dropped, not converted.
    op.execute("DELETE FROM api_tokens")
    with op.batch_alter_table("api_tokens") as batch:
        batch.add_column(sa.Column("id", sa.String(length=40), nullable=False))
        batch.add_column(sa.Column("tenant", sa.String(length=64), server_default="default", nullable=False))
        batch.add_column(sa.Column("name", sa.String(length=128), server_default="", nullable=False))
        batch.add_column(
            sa.Column("source", sa.String(length=16), server_default="configured", nullable=False)
        )
        batch.create_unique_constraint("uq_api_tokens_id", ["id"])
    op.add_column("jobs", sa.Column("tenant", sa.String(length=64), server_default="default", nullable=False))
    op.create_index(op.f("ix_jobs_tenant"), "jobs", ["tenant"], unique=False)
    op.create_index(op.f("ix_jobs_artifact_id"), "jobs", ["artifact_id"], unique=False)
    with op.batch_alter_table("idempotency_keys") as batch:
        batch.alter_column("key", type_=sa.String(length=160), existing_nullable=False)
    op.execute("UPDATE idempotency_keys SET key = 'default/' || key")  # the jobs so far: the default tenant's
    op.create_table(
        "asset_owners",
        sa.Column("asset_id", sa.String(length=80), nullable=False),
        sa.Column("tenant", sa.String(length=64), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("asset_id", "tenant"),
    )


def downgrade() -> None:
    op.drop_table("asset_owners")
    op.execute("DELETE FROM idempotency_keys WHERE key NOT LIKE 'default/%'")
    op.execute("UPDATE idempotency_keys SET key = substr(key, 9)")
    with op.batch_alter_table("idempotency_keys") as batch:
        batch.alter_column("key", type_=sa.String(length=80), existing_nullable=False)
    op.drop_index(op.f("ix_jobs_artifact_id"), table_name="jobs")
    op.drop_index(op.f("ix_jobs_tenant"), table_name="jobs")
    op.drop_column("jobs", "tenant")
    op.execute("DELETE FROM api_tokens")
    with op.batch_alter_table("api_tokens") as batch:
        batch.drop_constraint("uq_api_tokens_id", type_="unique")
        for column in ("source", "name", "tenant", "id"):
            batch.drop_column(column)
