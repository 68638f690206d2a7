"""The inference service's core, shared by the REST and gRPC adapters: the model cache, one batcher per
loaded model, request checks, limits, working-memory admission and timeouts. Every model call goes
through a batcher, so both adapters get the same merging, the same one-call-at-a-time guarantee and the
same errors.

Memory is bounded as a whole: loaded models by the cache's budget, and what requests allocate on top by
the working-memory budget (`admission`). A request's bytes are estimated before anything is converted
or run, from its body, its inputs at the operation's declared dtypes (twice: converted, then merged into
a batch) and the operation's declared costs per row and per call; the adapters encode the answer inside
the reservation, so the encoded copy is counted too.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
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
from services.inference.admission import MemoryPool
from services.inference.batching import Batcher
from services.inference.cache import ModelCache
from services.inference.errors import InvalidQuery, Overloaded, RequestTooLarge, UnsupportedOperation
from services.inference.inputs import checked_arrays, checked_params
from services.inference.loader import Loaded, load_artifact
from services.inference.metrics import InferenceMetrics
from services.inference.settings import InferenceSettings
from services.platform.errors import ServiceError
from workers.models.registry import RENDER, Answer, Operation
from workers.render.heap import return_freed_arrays

FRAME_SECONDS = "frame_seconds"  # in a render's meta: the model's time for the frame
TRIMS_PER_BUDGET = 4  # freed heap goes back to the OS after each quarter of the working budget is released


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
        return_freed_arrays()  # before a model builds a RayScene, which would keep them (workers.render.heap)
        self.metrics = InferenceMetrics()
        self.blobs = BlobStore(settings.shared.store)
        self.artifacts = ArtifactStore(self.blobs, settings.shared.store, checkpoint_root=settings.work_dir)
        self.cache = ModelCache(settings.memory_budget_bytes, self._load, self.metrics)
        self.reading, self.working = (
            MemoryPool(name, budget, settings.max_waiting, budget // TRIMS_PER_BUDGET, self.metrics)
            for name, budget in (("reading", settings.reading_bytes), ("working", settings.working_bytes))
        )

    def _load(self, artifact_id: str) -> Served:
        loaded = load_artifact(self.artifacts, artifact_id, self.device, self.settings.work_dir)
        batcher = Batcher(
            lambda operation, params, arrays: self._answer(loaded, operation, params, arrays),
            self.settings.max_batch_rows,
            self.settings.chunk_rows,
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
            if colon and field.startswith(("params.", "arrays.")) and " " not in field:
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

    @contextmanager
    def answering(
        self,
        artifact_id: str,
        operation: str,
        params: dict[str, Any],
        arrays: dict[str, np.ndarray],
        body_bytes: int,
    ) -> Iterator[tuple[Served, Answer]]:
        """The answer of one request, its working memory held until the block (which encodes it) ends;
        raises the service's errors (4xx), or Overloaded when it waits or runs past the timeout."""
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
            deadline = time.monotonic() + self.settings.request_timeout_s
            nbytes = self._admitted_bytes(spec, arrays, body_bytes, spec.params_bytes(loaded.model, typed))
            with self.working.reserved(nbytes, self.settings.request_timeout_s):
                inputs = checked_arrays(spec, arrays, self.settings.max_rows)
                future = served.batcher.submit(operation, spec, typed, inputs)
                try:
                    answer = future.result(timeout=max(deadline - time.monotonic(), 0.0))
                except FutureTimeout:
                    future.cancel()
                    raise Overloaded(
                        f"no answer within {self.settings.request_timeout_s} s; the model is busy, retry"
                    ) from None
                yield served, answer

    def _admitted_bytes(
        self, spec: Operation, arrays: dict[str, np.ndarray], body_bytes: int, params_bytes: int
    ) -> int:
        """The working memory a request will need, from its shapes and what its parameters ask for
        (`params_bytes`; nothing converted or run yet); RequestTooLarge naming its row input, or its
        parameters when they ask for most of it, when that is more than the whole budget."""
        known = {name: array for name, array in arrays.items() if name in spec.inputs}
        row_inputs = [a for n, a in known.items() if spec.inputs[n].rows and a.ndim]
        rows = max((len(a) for a in row_inputs), default=0)  # a 0-d array is refused by its shape check
        converted = sum(a.size * np.dtype(spec.inputs[n].dtype).itemsize for n, a in known.items())
        per_call = spec.call_bytes + params_bytes
        per_call += min(rows, self.settings.chunk_rows) * spec.activation_row_bytes
        nbytes = body_bytes + 2 * converted + rows * spec.row_bytes + per_call
        budget = self.settings.working_bytes
        if nbytes > budget:
            self.metrics.admission.labels("working", "too_large").inc()
            needs = (
                f"this request needs about {nbytes:,} bytes of working memory ({rows:,} rows); the "
                f"inference service's working-memory budget is {budget:,} bytes "
                "(NBAKE_INFERENCE_WORKING_BYTES)"
            )
            if 2 * params_bytes > nbytes:
                asked = f"{params_bytes:,} of them for what the parameters ask: ask for less"
                raise RequestTooLarge(f"{needs}, {asked}", "params")
            field = next((f"arrays.{n}" for n in spec.inputs if n in known), "params")
            per_row = nbytes / max(rows, 1)
            raise RequestTooLarge(
                f"{needs}, about {int(budget // per_row):,} rows of this operation: split it", field
            )
        return nbytes

    def admitted_body(self, nbytes: int) -> int:
        """`nbytes` (what receiving a body will take), or RequestTooLarge naming the body when that is more
        than the whole reading pool."""
        budget = self.settings.reading_bytes
        if nbytes > budget:
            self.metrics.admission.labels("reading", "too_large").inc()
            raise RequestTooLarge(
                f"receiving this body takes about {nbytes:,} bytes; the inference service's reading budget "
                f"is {budget:,} bytes (NBAKE_INFERENCE_READING_BYTES): send fewer rows per request",
                "body",
            )
        return nbytes

    @contextmanager
    def measured(self, operation: str):
        """Count the request under its outcome's status and time it."""
        start = time.perf_counter()
        status = 500
        try:
            yield
            status = 200
        except ServiceError as error:
            status = error.status
            raise
        except ArtifactNotFound:
            status = 404
            raise
        finally:
            self.metrics.requests.labels(operation, str(status)).inc()
            self.metrics.latency.labels(operation).observe(time.perf_counter() - start)
