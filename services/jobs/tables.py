"""The job database schema (SQLAlchemy 2 ORM): jobs, their events, idempotency keys, API tokens, which
tenants own which uploaded assets, and tenants' own quotas.

Alembic migrations in `migrations/` create exactly these tables; `test_jobs_db` checks that they agree.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import JSON, BigInteger, DateTime, Float, ForeignKey, Integer, String, Text, TypeDecorator
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


class UTCDateTime(TypeDecorator):
    """Aware UTC datetimes on every backend (SQLite drops the zone; this puts it back)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect) -> datetime | None:
        return value.astimezone(UTC) if value is not None else None

    def process_result_value(self, value: datetime | None, dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


DEFAULT_TENANT = "default"  # of configured tokens, and of everything made before tenants existed


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    type_annotation_map: ClassVar = {dict[str, Any]: JSON, datetime: UTCDateTime}


class Job(Base):
    """One submitted job. `seq` orders jobs for cursor pagination; `id` is the public name."""

    __tablename__ = "jobs"

    seq: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    id: Mapped[str] = mapped_column(String(40), unique=True)
    tenant: Mapped[str] = mapped_column(
        String(64), index=True, default=DEFAULT_TENANT, server_default=DEFAULT_TENANT
    )
    kind: Mapped[str] = mapped_column(String(64), index=True)
    state: Mapped[str] = mapped_column(String(16), index=True)
    scene_ref: Mapped[dict[str, Any]]  # how the user named the scene: builtin / asset / inline
    # the resolved SceneSpec's JSON is stored once in the artifact store, under this digest (scene_specs)
    scene_digest: Mapped[str] = mapped_column(String(80))
    scene_hash: Mapped[str] = mapped_column(String(80))
    preset: Mapped[str] = mapped_column(String(64))
    config: Mapped[dict[str, Any]]  # the resolved config
    seed: Mapped[int] = mapped_column(BigInteger)
    priority: Mapped[int] = mapped_column(Integer, default=0)
    code_version: Mapped[str] = mapped_column(String(80))
    idempotency_key: Mapped[str] = mapped_column(String(80), index=True)
    plan: Mapped[dict[str, Any] | None]
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer)
    cancel_requested: Mapped[bool] = mapped_column(default=False)
    error: Mapped[str | None] = mapped_column(Text)
    artifact_id: Mapped[str | None] = mapped_column(String(80), index=True)  # whose artifact is it: a job's
    progress: Mapped[dict[str, Any] | None]  # the latest progress event
    last_event_seq: Mapped[int] = mapped_column(Integer, default=0)
    lease_owner: Mapped[str | None] = mapped_column(String(255))
    lease_expires: Mapped[datetime | None]
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None]
    finished_at: Mapped[datetime | None]


class Event(Base):
    """What happened to a job, in order: `seq` counts up from 1 per job (the SSE event id)."""

    __tablename__ = "job_events"

    job_id: Mapped[str] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"), primary_key=True)
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    type: Mapped[str] = mapped_column(String(16))  # state | progress | log
    time: Mapped[datetime] = mapped_column(default=utcnow)
    data: Mapped[dict[str, Any]]


class IdempotencyKey(Base):
    """A content key (`<tenant>/content:<sha256>`) or a client's `Idempotency-Key` header
    (`<tenant>/header:<sha256>`): the tenant prefix keeps identical work of two tenants two jobs."""

    __tablename__ = "idempotency_keys"

    key: Mapped[str] = mapped_column(String(160), primary_key=True)
    job_id: Mapped[str] = mapped_column(ForeignKey("jobs.id", ondelete="CASCADE"))
    request_hash: Mapped[str] = mapped_column(String(80))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class ApiToken(Base):
    """A bearer token, stored as its sha256 (tokens are random, so a plain hash is enough), never in clear.
    `id` names it in listings and revocations; `source` is `configured` (NBAKE_TOKENS, replaced at every
    start) or `created` (through `POST /v1/tokens`, kept until revoked)."""

    __tablename__ = "api_tokens"

    token_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    id: Mapped[str] = mapped_column(String(40), unique=True)
    tenant: Mapped[str] = mapped_column(String(64), default=DEFAULT_TENANT, server_default=DEFAULT_TENANT)
    scope: Mapped[str] = mapped_column(String(16))
    name: Mapped[str] = mapped_column(String(128), server_default="")
    source: Mapped[str] = mapped_column(String(16), server_default="configured")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class AssetOwner(Base):
    """A tenant that uploaded an asset. Assets are content-addressed, so two tenants uploading the same
    files share its blobs and listing; each sees it only through its own row here."""

    __tablename__ = "asset_owners"

    asset_id: Mapped[str] = mapped_column(String(80), primary_key=True)
    tenant: Mapped[str] = mapped_column(String(64), primary_key=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class TenantQuota(Base):
    """A tenant's own limits (`services.jobs.quotas`); a NULL column takes the deployment's default."""

    __tablename__ = "tenant_quotas"

    tenant: Mapped[str] = mapped_column(String(64), primary_key=True)
    max_running: Mapped[int | None] = mapped_column(Integer)
    max_queued: Mapped[int | None] = mapped_column(Integer)
    max_compute_s: Mapped[float | None] = mapped_column(Float)
    max_priority: Mapped[int | None] = mapped_column(Integer)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow)
