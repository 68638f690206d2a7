"""Dynamic batching: concurrent requests for one model are merged row-wise into one call.

Each loaded model has one worker thread, so a model only ever runs one call at a time (torch and the
path tracer's intersector are not re-entered). The worker takes the first waiting request, then gathers
more with the same operation and parameters until `max_rows` rows or `max_wait_s` have passed, runs the
model on the concatenated arrays and hands each request its own rows back. Operations that are not
row-independent run one request per call on the same thread. The thread ends when idle and starts again
on the next request, so an evicted model leaves nothing running.

A batched call runs at most `chunk_rows` rows at a time and concatenates the chunks' outputs, so the
model's intermediate arrays and activations are bounded per call whatever the batch (or one request)
holds; the outputs themselves are the answer and are counted by the service's admission.
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from collections.abc import Callable, Collection
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel

from workers.models.registry import Answer, Operation

IDLE_EXIT_S = 5.0


@dataclass
class _Request:
    operation: str
    spec: Operation
    params: BaseModel
    arrays: dict[str, np.ndarray]
    future: Future

    @property
    def per_call(self) -> list[str]:
        return [name for name in self.arrays if self.spec.inputs[name].per_call]

    @property
    def rows(self) -> int:
        return next((len(a) for name, a in self.arrays.items() if self.spec.inputs[name].rows), 0)

    def key(self) -> tuple[str, str, tuple[str, ...], int]:
        """Requests merge only with equal parameters and the same inputs (optional ones may be absent), and
        one carrying a `per_call` input (its own environment map) with none."""
        alone = id(self) if self.per_call else 0
        return self.operation, self.params.model_dump_json(), tuple(sorted(self.arrays)), alone


def in_chunks(
    run: Callable[[dict[str, np.ndarray]], Answer],
    arrays: dict[str, np.ndarray],
    rows: int,
    chunk_rows: int,
    per_call: Collection[str] = (),
) -> Answer:
    """`run` on at most `chunk_rows` rows at a time, each chunk with the whole of the `per_call` inputs,
    outputs concatenated (meta: the first chunk's, as every chunk of a row-independent operation says the
    same)."""
    if rows <= chunk_rows:
        return run(arrays)
    parts = [
        run(
            {
                name: array if name in per_call else array[start : start + chunk_rows]
                for name, array in arrays.items()
            }
        )
        for start in range(0, rows, chunk_rows)
    ]
    merged = {name: np.concatenate([p.arrays[name] for p in parts]) for name in parts[0].arrays}
    return Answer(merged, parts[0].meta)


def _split(answer: Answer, counts: list[int]) -> list[Answer]:
    bounds = np.cumsum([0, *counts])
    return [
        Answer({name: array[start:stop] for name, array in answer.arrays.items()}, answer.meta)
        for start, stop in itertools.pairwise(bounds)
    ]


class Batcher:
    """`submit` gives a Future of the request's own Answer; `run(operation, params, arrays)` is the model."""

    def __init__(
        self,
        run: Callable[[str, BaseModel, dict[str, np.ndarray]], Answer],
        max_rows: int,
        chunk_rows: int,
        max_wait_s: float,
        on_batch: Callable[[int, int], None],
    ) -> None:
        self.run, self.max_rows, self.chunk_rows = run, max_rows, chunk_rows
        self.max_wait_s, self.on_batch = max_wait_s, on_batch
        self.queue: queue.Queue[_Request] = queue.Queue()
        self.lock = threading.Lock()
        self.thread: threading.Thread | None = None
        self.carried: _Request | None = None  # taken from the queue but not mergeable with the last batch

    def submit(
        self, operation: str, spec: Operation, params: BaseModel, arrays: dict[str, np.ndarray]
    ) -> Future:
        future: Future = Future()
        with self.lock:
            self.queue.put(_Request(operation, spec, params, arrays, future))
            if self.thread is None:
                self.thread = threading.Thread(target=self._work, name="nbake-inference-batch", daemon=True)
                self.thread.start()
        return future

    def _next(self, timeout: float) -> _Request | None:
        if self.carried is not None:
            request, self.carried = self.carried, None
            return request
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def _work(self) -> None:
        while True:
            first = self._next(IDLE_EXIT_S)
            if first is None:
                with self.lock:
                    if self.queue.empty():
                        self.thread = None
                        return
                continue
            if first.future.set_running_or_notify_cancel():  # False: its caller gave up waiting
                self._run(self._gather(first))

    def _gather(self, first: _Request) -> list[_Request]:
        batch, rows = [first], first.rows
        if not first.spec.batched:
            return batch
        deadline = time.monotonic() + self.max_wait_s
        while rows < self.max_rows:
            request = self._next(max(deadline - time.monotonic(), 0.0))
            if request is None:
                break
            if request.key() != first.key() or rows + request.rows > self.max_rows:
                self.carried = request
                break
            if request.future.set_running_or_notify_cancel():
                batch.append(request)
                rows += request.rows
        return batch

    def _run(self, batch: list[_Request]) -> None:
        first = batch[0]

        def run(arrays: dict[str, np.ndarray]) -> Answer:
            return self.run(first.operation, first.params, arrays)

        try:
            if not first.spec.batched:
                answers = [run(first.arrays)]
            else:
                rows = [r.rows for r in batch]
                merged = (
                    first.arrays
                    if len(batch) == 1
                    else {name: np.concatenate([r.arrays[name] for r in batch]) for name in first.arrays}
                )
                answers = _split(in_chunks(run, merged, sum(rows), self.chunk_rows, first.per_call), rows)
        except Exception as error:  # every request of the batch learns why
            for request in batch:
                request.future.set_exception(error)
            return
        self.on_batch(sum(r.rows for r in batch), len(batch))
        for request, answer in zip(batch, answers, strict=True):
            request.future.set_result(answer)
