"""Typed results: the same shapes the server's REST schemas have (a contract test compares them with the
server's OpenAPI document), whichever transport (HTTP or gRPC) produced them.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field, PrivateAttr

from neuralbake_client.states import JobState


class Job(BaseModel):
    id: str
    tenant: str
    kind: str
    state: JobState
    scene: dict[str, str]
    scene_hash: str
    preset: str
    config: dict[str, Any]
    seed: int
    priority: int
    code_version: str
    idempotency_key: str
    plan: dict[str, Any] | None = None
    attempts: int
    max_attempts: int
    cancel_requested: bool
    error: str | None = None
    artifact_id: str | None = None
    progress: dict[str, Any] | None = Field(None, description="The latest progress event's data.")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    links: dict[str, str] = Field(default_factory=dict, description="REST links (empty over gRPC).")
    _reused: bool = PrivateAttr(False)

    @property
    def reused(self) -> bool:
        """True when a submission got an existing job back (identical work, or the same idempotency key):
        the server answered 200 rather than 201 (gRPC: `created` false)."""
        return self._reused


class JobList(BaseModel):
    items: list[Job]
    next_cursor: str | None = None


class Progress(BaseModel):
    """What a `progress` event says: step of total, loss, samples per second, seconds to go."""

    step: int | None = None
    total: int | None = None
    loss: float | None = None
    samples_per_s: float | None = None
    eta_s: float | None = None


class JobEvent(BaseModel):
    """One event of a job: `type` is `state`, `progress` or `log`; `seq` counts from 1 per job."""

    job_id: str
    seq: int
    type: str
    time: datetime
    data: dict[str, Any]

    @property
    def state(self) -> JobState | None:
        """The new state of a `state` event."""
        return JobState(self.data["state"]) if self.type == "state" else None

    @property
    def progress(self) -> Progress | None:
        return Progress.model_validate(self.data) if self.type == "progress" else None

    @property
    def final(self) -> bool:
        return self.state is not None and self.state.terminal


class FileEntry(BaseModel):
    name: str
    media_type: str
    digest: str
    size: int


class Asset(BaseModel):
    asset_id: str
    scene_file: str
    scene_name: str
    files: list[FileEntry]
    created: datetime


class Manifest(BaseModel):
    schema_version: int
    media_type: str
    artifact_id: str
    kind: str
    job_id: str
    scene_hash: str
    config: dict[str, Any]
    code_version: str
    metrics: dict[str, float]
    created: datetime
    files: list[FileEntry]
    annotations: dict[str, str] = Field(default_factory=dict)

    def file(self, name: str) -> FileEntry:
        for entry in self.files:
            if entry.name == name:
                return entry
        raise KeyError(f"{name!r} is not in artifact {self.artifact_id} ({', '.join(self.names())})")

    def names(self) -> list[str]:
        return [entry.name for entry in self.files]


class Token(BaseModel):
    """A bearer token as an admin lists it: never its secret. `source` is `configured` (NBAKE_TOKENS) or
    `created` (`create_token`, revocable)."""

    id: str
    tenant: str
    scope: str
    name: str
    source: str
    created_at: datetime


class CreatedToken(Token):
    token: str = Field(description="The secret, shown only when the token is created.")


class QuotaLimits(BaseModel):
    """A tenant's limits; None: no limit (in `TenantQuotas.own`: the deployment's default holds)."""

    max_running: int | None = None
    max_queued: int | None = None
    max_compute_s: float | None = None
    max_priority: int | None = None


class QuotaUse(BaseModel):
    running: int
    queued: int
    compute_s: float = Field(description="The plans' estimated seconds of the queued and running jobs.")


class TenantQuotas(BaseModel):
    """A tenant's quotas: in force (`limits`), its own, the deployment's defaults, and its use now."""

    tenant: str
    limits: QuotaLimits
    own: QuotaLimits
    defaults: QuotaLimits
    use: QuotaUse
    updated_at: datetime | None = None


class ModelInfo(BaseModel):
    """A model the inference service holds in memory (`operations`: `query`, `render`)."""

    artifact_id: str
    kind: str
    operations: list[str]
    bytes: int
    device: str


class PresetInfo(BaseModel):
    name: str
    config: dict[str, Any] = Field(description="The config this preset resolves to, without overrides.")


class KindInfo(BaseModel):
    """A model kind the server runs: `trains` (a trained model with a speed-against-error report, or a
    path-traced image), its presets, its smallest example job and its config's JSON schema."""

    name: str
    trains: bool
    presets: list[PresetInfo]
    example_scene: str
    example_overrides: dict[str, Any]
    config_schema: dict[str, Any]

    def preset(self, name: str) -> PresetInfo:
        for preset in self.presets:
            if preset.name == name:
                return preset
        raise KeyError(f"{name!r}: the presets are {', '.join(p.name for p in self.presets)}")


class SceneInfo(BaseModel):
    name: str
    description: str
