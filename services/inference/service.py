"""The inference service's core, shared by the REST and gRPC adapters: the model cache, one batcher per
loaded model, request checks, limits and timeouts. Every model call goes through a batcher, so both
adapters get the same merging, the same one-call-at-a-time guarantee and the same errors."""

from __future__ import annotations

import time
from concurrent.futures import TimeoutError as FutureTimeout
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from pydantic import BaseModel

from services.artifacts.artifacts import ArtifactNotFound, ArtifactStore
from services.artifacts.digests import known_digest
from services.artifacts.store import BlobStore
from services.inference.batching import Batcher
from services.inference.cache import ModelCache
from services.inference.errors import InvalidQuery, Overloaded, UnsupportedOperation
from services.inference.inputs import checked_arrays, checked_params
from services.inference.loader import Loaded, load_artifact
from services.inference.metrics import InferenceMetrics
from services.inference.settings import InferenceSettings
from services.jobs.errors import JobServiceError
from workers.models.registry import RENDER, Answer

FRAME_SECONDS = "frame_seconds"  # in a render's meta: the model's time for the frame


def server_timing(answer: Answer) -> str:
    """The W3C Server-Timing value of a render's frame time: `frame;dur=<ms>`, sent by REST as a header
    and by gRPC as metadata, which clients print."""
    return f"frame;dur={answer.meta[FRAME_SECONDS] * 1000:.3f}"


class ModelInfo(BaseModel):
    artifact_id: str
    kind: str
    operations: list[str]
    bytes: int
    device: str


@dataclass
class Served:
    """A loaded artifact and the batcher in front of it."""

    loaded: Loaded
    batcher: Batcher = field(repr=False)

    @property
    def nbytes(self) -> int:
        return self.loaded.nbytes

    @property
    def artifact_id(self) -> str:
        return self.loaded.artifact_id

    def info(self) -> ModelInfo:
        loaded = self.loaded
        operations = sorted(loaded.inference.operations)
        return ModelInfo(
            artifact_id=loaded.artifact_id,
            kind=loaded.kind,
            operations=operations,
            bytes=loaded.nbytes,
            device=loaded.device,
        )


class InferenceService:
    def __init__(self, settings: InferenceSettings) -> None:
        self.settings = settings
        self.device = settings.resolved_device()
        torch.set_num_threads(settings.torch_threads)  # one process, one setting: every model call shares it
        self.metrics = InferenceMetrics()
        self.blobs = BlobStore(settings.shared.store)
        self.artifacts = ArtifactStore(self.blobs, settings.shared.store, checkpoint_root=settings.work_dir)
        self.cache = ModelCache(settings.memory_budget_bytes, self._load, self.metrics)

    def _load(self, artifact_id: str) -> Served:
        loaded = load_artifact(self.artifacts, artifact_id, self.device, self.settings.work_dir)
        batcher = Batcher(
            lambda operation, params, arrays: self._answer(loaded, operation, params, arrays),
            self.settings.max_batch_rows,
            self.settings.max_wait_ms / 1000,
            self._count_batch,
        )
        return Served(loaded, batcher)

    @staticmethod
    def _answer(loaded: Loaded, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer:
        """The model's answer; a render's also says how long the model took to make it (its frame time)."""
        start = time.perf_counter()
        try:
            answer = loaded.model.answer(operation, params, arrays)
        except ValueError as error:  # a kind refuses input it cannot answer (e.g. an unknown layer)
            field, colon, detail = str(error).partition(": ")  # "params.level: ..." names its field
            if colon and field.startswith("params.") and " " not in field:
                raise InvalidQuery(detail, field) from None
            raise InvalidQuery(str(error)) from None
        if operation != RENDER:
            return answer
        return Answer(answer.arrays, {**answer.meta, FRAME_SECONDS: time.perf_counter() - start})

    def _count_batch(self, rows: int, requests: int) -> None:
        self.metrics.batch_rows.observe(rows)
        self.metrics.batch_requests.observe(requests)

    # ------------------------------------------------------------------ operations

    def served(self, artifact_id: str) -> Served:
        return self.cache.get(known_digest(artifact_id, ArtifactNotFound))

    def models(self) -> list[ModelInfo]:
        return [entry.info() for entry in self.cache.snapshot()]

    def call(
        self, artifact_id: str, operation: str, params: dict[str, Any], arrays: dict[str, np.ndarray]
    ) -> tuple[Served, Answer]:
        """The answer of one request; raises the service's errors (4xx) or Overloaded on timeout."""
        with self.measured(operation):
            served = self.served(artifact_id)
            loaded = served.loaded
            spec = loaded.inference.operations.get(operation)
            if spec is None:
                supported = ", ".join(sorted(loaded.inference.operations)) or "nothing"
                raise UnsupportedOperation(
                    f"{artifact_id} is a {loaded.kind!r} artifact, which does not support {operation} "
                    f"(it supports: {supported})"
                )
            typed = checked_params(spec, params)
            inputs = checked_arrays(spec, arrays, self.settings.max_rows)
            future = served.batcher.submit(operation, spec, typed, inputs)
            try:
                return served, future.result(timeout=self.settings.request_timeout_s)
            except FutureTimeout:
                future.cancel()
                raise Overloaded(
                    f"no answer within {self.settings.request_timeout_s} s; the model is busy, retry"
                ) from None

    @contextmanager
    def measured(self, operation: str):
        """Count the request under its outcome's status and time it."""
        start = time.perf_counter()
        status = 500
        try:
            yield
            status = 200
        except JobServiceError as error:
            status = error.status
            raise
        except ArtifactNotFound:
            status = 404
            raise
        finally:
            self.metrics.requests.labels(operation, str(status)).inc()
            self.metrics.latency.labels(operation).observe(time.perf_counter() - start)
