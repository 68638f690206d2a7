"""Everything a server instance is configured with; `from_env` reads the `NBAKE_*` variables."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from services.artifacts.staging import UploadLimits


class ServiceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    data_dir: Path
    database_url: str | None = Field(None, description="default: SQLite file <data_dir>/jobs.db (WAL)")
    database_schema: str | None = Field(None, description="PostgreSQL schema (one per deployment or test)")
    store_url: str | None = Field(None, description="default: <data_dir>/store; s3://bucket/prefix at scale")
    tokens: str | None = Field(None, description="`token:scope,...`; scopes read, submit, admin")
    tokens_file: Path | None = Field(None, description="one `token:scope` per line; # comments")
    max_running: int = Field(1, ge=1, description="jobs running at once on this scheduler")
    max_attempts: int = Field(3, ge=1, description="runs of a job when its infrastructure keeps failing")
    max_json_bytes: int = Field(1 << 20, ge=1024, description="largest request body outside uploads")
    upload_limits: UploadLimits = UploadLimits()
    scheduler_owner: str | None = Field(None, description="default: host name and data dir")
    lease_s: float = Field(30.0, gt=0, description="a RUNNING job whose owner is silent this long is adopted")
    scheduling: bool = Field(True, description="run the scheduler here; False for API-only replicas")
    max_job_seconds: float = Field(
        7 * 86_400.0, gt=0, description="refuse a job whose plan estimates more (the cost ceiling)"
    )

    @classmethod
    def from_env(cls, data_dir: Path, **overrides) -> ServiceSettings:
        env = {
            "database_url": os.environ.get("NBAKE_DATABASE_URL"),
            "database_schema": os.environ.get("NBAKE_DATABASE_SCHEMA"),
            "store_url": os.environ.get("NBAKE_STORE_URL"),
            "tokens": os.environ.get("NBAKE_TOKENS"),
            "tokens_file": os.environ.get("NBAKE_TOKENS_FILE"),
            "max_running": os.environ.get("NBAKE_MAX_RUNNING"),
        }
        values = {k: v for k, v in env.items() if v} | {k: v for k, v in overrides.items() if v is not None}
        return cls(data_dir=data_dir, **values)

    @property
    def db_url(self) -> str:
        return self.database_url or f"sqlite:///{(self.data_dir / 'jobs.db').resolve()}"

    @property
    def store(self) -> str:
        return self.store_url or str((self.data_dir / "store").resolve())

    @property
    def owner(self) -> str:
        return self.scheduler_owner or f"{socket.gethostname()}:{self.data_dir.resolve()}"
