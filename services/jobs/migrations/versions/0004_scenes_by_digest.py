"""scenes by digest: a job row names its resolved scene by the digest of the scene's JSON, which is stored
once in the artifact store (`services.jobs.scene_specs`), instead of holding the JSON

Revision ID: 0004
Revises: 0003

The jobs' scenes are moved into the store here, so no legacy column stays behind to be read beside the
store for ever: `Database.migrate` is given the store (`config.attributes["scene_specs"]`; the server
always passes it). A database holding jobs is refused without it, the transaction rolled back.

The new column is added NOT NULL with an empty default rather than filled and then altered: SQLite alters
a column only by copying the table, and dropping the old `jobs` would cascade to its events. The default is
dropped again where ALTER can (PostgreSQL).
"""

import sqlalchemy as sa
from alembic import context, op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None

jobs = sa.table(
    "jobs", sa.column("id", sa.String), sa.column("scene", sa.JSON), sa.column("scene_digest", sa.String)
)


def upgrade() -> None:
    specs = _scene_specs()
    op.add_column("jobs", sa.Column("scene_digest", sa.String(length=80), server_default="", nullable=False))
    connection = op.get_bind()
    for job_id in connection.execute(sa.select(jobs.c.id)).scalars().all():  # one scene in memory at once
        scene = connection.execute(sa.select(jobs.c.scene).where(jobs.c.id == job_id)).scalar_one()
        connection.execute(jobs.update().where(jobs.c.id == job_id).values(scene_digest=specs.put(scene)))
    if op.get_context().dialect.name != "sqlite":
        op.alter_column("jobs", "scene_digest", server_default=None)
    op.drop_column("jobs", "scene")


def downgrade() -> None:
    specs = _scene_specs()
    op.add_column("jobs", sa.Column("scene", sa.JSON(), server_default="{}", nullable=False))
    connection = op.get_bind()
    for job_id, digest in connection.execute(sa.select(jobs.c.id, jobs.c.scene_digest)).all():
        connection.execute(jobs.update().where(jobs.c.id == job_id).values(scene=specs.get(digest)))
    if op.get_context().dialect.name != "sqlite":
        op.alter_column("jobs", "scene", server_default=None)
    op.drop_column("jobs", "scene_digest")


def _scene_specs():
    """The store the scenes move to or from; a RuntimeError when the database has jobs and none was given."""
    specs = context.config.attributes.get("scene_specs")
    has_jobs = op.get_bind().execute(sa.select(sa.func.count()).select_from(jobs)).scalar()
    if specs is None and has_jobs:
        raise RuntimeError(
            "migration 0004 moves the jobs' scenes into the artifact store: migrate through `nbake serve`, "
            "or call Database.migrate with the store's SceneSpecs"
        )
    return specs
