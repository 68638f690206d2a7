"""Response bodies of the REST API (request bodies are the job service's own models)."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field

from services.jobs.states import JobState
from services.jobs.tables import Job


class JobView(BaseModel):
    id: str
    tenant: str = Field(description="The submitting token's tenant (an admin token lists every tenant's).")
    kind: str
    state: JobState
    scene: dict[str, str] = Field(description="How the scene was named: source builtin, asset or inline.")
    scene_hash: str
    preset: str
    config: dict[str, Any] = Field(description="The resolved config (preset plus overrides).")
    seed: int
    priority: int
    code_version: str
    idempotency_key: str
    plan: dict[str, Any] | None
    attempts: int
    max_attempts: int
    cancel_requested: bool
    error: str | None
    artifact_id: str | None
    progress: dict[str, Any] | None = Field(description="The latest progress event.")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    links: dict[str, str]

    @classmethod
    def of(cls, job: Job) -> JobView:
        links = {"self": f"/v1/jobs/{job.id}", "events": f"/v1/jobs/{job.id}/events"}
        if job.artifact_id:
            links["artifact"] = f"/v1/artifacts/{job.artifact_id}"
        fields = {name: getattr(job, name) for name in cls.model_fields if name not in ("scene", "links")}
        return cls(**fields, scene=job.scene_ref, links=links)


class JobList(BaseModel):
    items: list[JobView]
    next_cursor: str | None = Field(description="Pass as `cursor` for the next page; null on the last page.")


class EventView(BaseModel):
    """The `data` of one server-sent event; its SSE `id` is `seq`, its SSE `event` is `type`."""

    job_id: str
    seq: int
    type: str = Field(
        description="state, progress, log, or resume (progress went back to a checkpoint's step after a "
        "restart: `from_step`, `to_step`, `attempt`)"
    )
    time: datetime
    data: dict[str, Any]
