"""What an inference server is configured with. The database (for tokens) and the artifact store come
from the same `NBAKE_*` settings as the job server's (`services.platform.settings`), so both read one store
and share one set of tokens."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from pydantic import BaseModel, ConfigDict, Field

from services.platform.settings import SharedSettings, env_values


class InferenceSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ENV: ClassVar[dict[str, str]] = {
        "memory_budget_bytes": "NBAKE_INFERENCE_MEMORY_BYTES",
        "working_bytes": "NBAKE_INFERENCE_WORKING_BYTES",
        "reading_bytes": "NBAKE_INFERENCE_READING_BYTES",
        "device": "NBAKE_INFERENCE_DEVICE",
    }

    shared: SharedSettings = Field(description="what the job server reads too: its database and store")
    memory_budget_bytes: int = Field(1 << 30, ge=1, description="loaded models beyond it evict the LRU one")
    working_bytes: int = Field(
        256 << 20,
        ge=1 << 20,
        description="what requests in flight may allocate between them (inputs, outputs, activations): a "
        "request needing more than all of it gets a 413, others wait their turn",
    )
    reading_bytes: int = Field(
        128 << 20,
        ge=1 << 20,
        description="what REST bodies being received may take between them, admitted by Content-Length "
        "before they are read: a body needing more than all of it gets a 413",
    )
    max_waiting: int = Field(256, ge=0, description="requests waiting for memory, per pool; more get a 503")
    # As many as a batch merges: each call pays a fixed cost (lsnif: a broad phase per instance), and the
    # inference load bench (64 clients, 30 s) served 1500 requests at 16384 and 2193 at 65536 (8192 had
    # halved it again). The activations of a 65536-ray lsnif call are about 140 MB; smaller requests
    # reserve theirs row by row, so chunks bound only what one large request would take at once.
    chunk_rows: int = Field(
        1 << 16, ge=1, description="rows one model call runs at a time: bounds activation memory per call"
    )
    max_batch_rows: int = Field(1 << 16, ge=1, description="rows one batched model call may merge")
    max_wait_ms: float = Field(2.0, ge=0, description="how long a batch waits for more requests")
    max_rows: int = Field(1 << 20, ge=1, description="rows (rays, pixels) one request may ask for")
    request_timeout_s: float = Field(30.0, gt=0, description="a request waiting longer gets a 503")
    max_body_bytes: int = Field(64 << 20, ge=1024, description="largest request body")
    torch_threads: int = Field(
        1, ge=1, description="intra-op threads per model call; more oversubscribe the cores HTTP also needs"
    )
    device: str = Field("auto", description="`auto` (CUDA when present, else CPU), `cpu` or `cuda[:n]`")

    @classmethod
    def from_env(cls, data_dir: Path, **overrides) -> InferenceSettings:
        return cls(shared=SharedSettings.from_env(data_dir), **env_values(cls.ENV, overrides))

    @property
    def work_dir(self) -> Path:
        """Where artifacts are downloaded (verified) before loading; nothing stays there."""
        return self.shared.data_dir / "inference"

    def resolved_device(self) -> str:
        if self.device != "auto":
            return self.device
        import torch  # only where models are evaluated

        return "cuda" if torch.cuda.is_available() else "cpu"
