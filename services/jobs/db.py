"""One Database object over SQLite (WAL, the embedded default) or PostgreSQL, with the same code.

SQLite writes begin with `BEGIN IMMEDIATE`: a deferred transaction that reads and then writes can
fail at once with "database is locked" when another writer got in between; an immediate one waits
for `busy_timeout` instead. PostgreSQL writes rely on row locks (`with_for_update`).

PostgreSQL reads run in autocommit: under READ COMMITTED each statement takes its own snapshot inside a
transaction too, so BEGIN and ROLLBACK would only add two round trips to every read (an authenticated
repeated submission makes two reads).

PostgreSQL connections are kept, not opened per burst: the pool holds as many as the server's threads can
use at once (`POOL_SIZE`; with 8 kept and 32 overflow, a load of 200 clients opened and closed connections
all the time: a backend process started for each). A connection is pinged before use only when it has sat
idle (`PING_IDLE_S`): one that is busy answered a moment ago, and a ping per checkout was a round trip per
read. After a database restart the first failing statement marks every older connection stale anyway.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from alembic import command
from alembic.config import Config
from sqlalchemy import create_engine, event, text
from sqlalchemy.engine import URL, Engine, make_url
from sqlalchemy.exc import DisconnectionError
from sqlalchemy.orm import Session, sessionmaker

if TYPE_CHECKING:
    from services.jobs.scene_specs import SceneSpecs

MIGRATIONS = Path(__file__).with_name("migrations")
MIGRATION_LOCK = 0x6E62616B65  # "nbake": the PostgreSQL advisory lock key that serialises migrations
_SCHEMA_NAME = re.compile(r"^[a-z_][a-z0-9_]{0,62}$")
POOL_SIZE = 40  # anyio's default thread limit: the most REST requests that hold a connection at once
POOL_OVERFLOW = 16  # for the gRPC server's and the scheduler's threads; opened and closed as needed
PING_IDLE_S = 1.0  # a pooled PostgreSQL connection idle longer than this is pinged before it is used


def normalize_url(url: str) -> URL:
    """`postgresql://` and `postgres://` mean psycopg 3 here (SQLAlchemy would pick psycopg2)."""
    parsed = make_url(url.replace("postgres://", "postgresql://", 1))
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")
    return parsed


class Database:
    """Engine, sessions and migrations. `schema` (PostgreSQL only) isolates one deployment or test run."""

    def __init__(self, url: str, schema: str | None = None):
        self.url = normalize_url(url)
        self.schema = schema
        self.is_sqlite = self.url.get_backend_name() == "sqlite"
        if schema is not None and (self.is_sqlite or not _SCHEMA_NAME.match(schema)):
            raise ValueError(f"schema {schema!r}: a lower-case identifier, and only with PostgreSQL")
        self.engine = self._engine()
        reads = self.engine if self.is_sqlite else self.engine.execution_options(isolation_level="AUTOCOMMIT")
        self._read = sessionmaker(reads, expire_on_commit=False)
        self._write = sessionmaker(self.engine.execution_options(immediate=True), expire_on_commit=False)

    def _engine(self) -> Engine:
        if self.is_sqlite:
            engine = create_engine(
                self.url,
                connect_args={"check_same_thread": False, "timeout": 30},
                pool_size=8,
                max_overflow=32,
            )
            event.listen(engine, "connect", _sqlite_connect)
            event.listen(engine, "begin", _sqlite_begin)
            return engine
        args = {"options": f"-csearch_path={self.schema}"} if self.schema else {}
        engine = create_engine(self.url, connect_args=args, pool_size=POOL_SIZE, max_overflow=POOL_OVERFLOW)
        event.listen(engine, "connect", _mark_used)
        event.listen(engine, "checkin", _mark_used)
        event.listen(engine, "checkout", lambda dbapi, record, _proxy: _ping_if_idle(engine, dbapi, record))
        return engine

    @contextmanager
    def reading(self) -> Iterator[Session]:
        with self._read() as session:
            yield session

    @contextmanager
    def writing(self) -> Iterator[Session]:
        """A transaction committed on success and rolled back on any exception."""
        with self._write() as session, session.begin():
            yield session

    @contextmanager
    def writing_alone(self) -> Iterator[Session]:
        """`writing`, serialised with every replica's (the migration lock on PostgreSQL; SQLite's BEGIN
        IMMEDIATE already is): for start-up work that replaces rows, which replicas starting together
        would otherwise interleave."""
        with self.writing() as session:
            if not self.is_sqlite:
                session.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK})
            yield session

    def migrate(self, scene_specs: SceneSpecs | None = None) -> None:
        """Bring the schema to the newest Alembic revision (run at every start; a no-op when current).

        `scene_specs` is the store that migration 0004 moves the jobs' scenes into: needed only to migrate
        a database that holds jobs from before it (the server always passes it)."""
        with self.engine.begin() as connection:
            if not self.is_sqlite:  # replicas starting together migrate one after another
                connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK})
            if self.schema:
                connection.execute(text(f'CREATE SCHEMA IF NOT EXISTS "{self.schema}"'))
            config = Config()
            config.set_main_option("script_location", str(MIGRATIONS))
            config.attributes["connection"] = connection
            config.attributes["scene_specs"] = scene_specs
            command.upgrade(config, "head")

    def ping(self) -> None:
        with self.engine.connect() as connection:
            connection.execute(text("SELECT 1"))

    def dispose(self) -> None:
        self.engine.dispose()


def _mark_used(_dbapi_connection, record) -> None:
    record.info["used"] = time.monotonic()


def _ping_if_idle(engine: Engine, dbapi_connection, record) -> None:
    """SQLAlchemy's pre-ping, for a connection idle over `PING_IDLE_S` only; a dead one is replaced."""
    if time.monotonic() - record.info.get("used", 0.0) <= PING_IDLE_S:
        return
    try:
        engine.dialect.do_ping(dbapi_connection)
    except engine.dialect.loaded_dbapi.Error as error:
        raise DisconnectionError(str(error)) from error


def _sqlite_connect(dbapi_connection, _record) -> None:
    dbapi_connection.isolation_level = None  # SQLAlchemy's "begin" hook below issues BEGIN itself
    cursor = dbapi_connection.cursor()
    for pragma in ("journal_mode=WAL", "synchronous=NORMAL", "foreign_keys=ON", "busy_timeout=30000"):
        cursor.execute(f"PRAGMA {pragma}")
    cursor.close()


def _sqlite_begin(connection) -> None:
    immediate = connection.get_execution_options().get("immediate", False)
    connection.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")
