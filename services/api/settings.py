"""Everything a job server instance is configured with, on top of what every server reads alike
(`services.platform.settings`); `from_env` reads the `NBAKE_*` variables."""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import ClassVar

from pydantic import Field

from services.artifacts.staging import UploadLimits
from services.jobs.quotas import QuotaLimits
from services.platform.settings import SharedSettings

# Every tenant's quotas unless it has its own: a thousand queued jobs (a bound on a runaway script; the
# benches queue a few hundred), no more estimated compute than the longest job allowed (max_job_seconds),
# priorities up to 100 of the API's 1000; running jobs unlimited beyond the scheduler's own max_running.
DEFAULT_TENANT_QUOTAS = QuotaLimits(max_queued=1000, max_compute_s=7 * 86_400.0, max_priority=100)
NO_LIMIT = "none"  # an NBAKE_TENANT_MAX_* value that lifts the limit


class ServiceSettings(SharedSettings):
    ENV: ClassVar[dict[str, str]] = SharedSettings.ENV | {
        "tokens": "NBAKE_TOKENS",
        "tokens_file": "NBAKE_TOKENS_FILE",
        "max_running": "NBAKE_MAX_RUNNING",
    }

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
    tenant_quotas: QuotaLimits = Field(
        DEFAULT_TENANT_QUOTAS, description="every tenant's quotas unless `nbake tokens quota` sets its own"
    )

    @classmethod
    def from_env(cls, data_dir: Path, **overrides) -> ServiceSettings:
        return super().from_env(data_dir, **{"tenant_quotas": tenant_quotas_from_env()} | overrides)

    @property
    def owner(self) -> str:
        return self.scheduler_owner or f"{socket.gethostname()}:{self.data_dir.resolve()}"


def tenant_quotas_from_env() -> QuotaLimits:
    """DEFAULT_TENANT_QUOTAS with NBAKE_TENANT_MAX_RUNNING, _MAX_QUEUED, _MAX_COMPUTE_S and _MAX_PRIORITY in
    place (`none`: no limit)."""
    values = DEFAULT_TENANT_QUOTAS.model_dump()
    for name in values:
        value = os.environ.get(f"NBAKE_TENANT_{name.upper()}")
        if value:
            values[name] = None if value.strip().lower() == NO_LIMIT else value
    return QuotaLimits.model_validate(values)
