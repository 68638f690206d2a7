"""Alembic environment: runs on the connection `Database.migrate` passes in (never reads alembic.ini)."""

from alembic import context

from services.jobs.tables import Base

context.configure(connection=context.config.attributes["connection"], target_metadata=Base.metadata)
with context.begin_transaction():
    context.run_migrations()
