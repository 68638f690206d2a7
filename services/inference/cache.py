"""Cached models, least recently used first out, bounded by a memory budget.

A model is loaded once however many requests ask for it at the same time (one loader per id), outside
the cache's lock, so loading one artifact never blocks answers from the others. Loading a model that
does not fit evicts least recently used ones until it does; one larger than the whole budget is refused.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Protocol

from services.inference.errors import ArtifactRefused
from services.inference.metrics import InferenceMetrics


class Cached(Protocol):
    artifact_id: str
    nbytes: int


class ModelCache:
    def __init__(self, budget_bytes: int, load: Callable[[str], Cached], metrics: InferenceMetrics) -> None:
        self.budget, self.load, self.metrics = budget_bytes, load, metrics
        self.entries: OrderedDict[str, Cached] = OrderedDict()
        self.lock = threading.Lock()
        self.loading: dict[str, threading.Lock] = {}

    def _lookup(self, artifact_id: str) -> Cached | None:
        entry = self.entries.get(artifact_id)
        if entry is not None:
            self.entries.move_to_end(artifact_id)
        return entry

    def get(self, artifact_id: str) -> Cached:
        with self.lock:
            entry = self._lookup(artifact_id)
            if entry is not None:
                self.metrics.cache.labels("hit").inc()
                return entry
            gate = self.loading.setdefault(artifact_id, threading.Lock())
        with gate:
            with self.lock:
                entry = self._lookup(artifact_id)  # loaded by the caller we waited for
            if entry is not None:
                self.metrics.cache.labels("hit").inc()
                return entry
            self.metrics.cache.labels("miss").inc()
            try:
                entry = self.load(artifact_id)
                self._insert(entry)
            finally:
                with self.lock:
                    self.loading.pop(artifact_id, None)
        return entry

    def _insert(self, entry: Cached) -> None:
        if entry.nbytes > self.budget:
            raise ArtifactRefused(
                f"{entry.artifact_id} needs {entry.nbytes} bytes loaded; the memory budget is {self.budget} "
                "(raise NBAKE_INFERENCE_MEMORY_BYTES)"
            )
        with self.lock:
            while self.entries and self.used() + entry.nbytes > self.budget:
                self.entries.popitem(last=False)
                self.metrics.cache.labels("eviction").inc()
            self.entries[entry.artifact_id] = entry
            self.metrics.loaded_bytes.set(self.used())
            self.metrics.loaded_models.set(len(self.entries))

    def used(self) -> int:
        return sum(e.nbytes for e in self.entries.values())

    def snapshot(self) -> list[Cached]:
        """Cached models, most recently used last."""
        with self.lock:
            return list(self.entries.values())
