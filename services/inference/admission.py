"""Admission of requests by the memory they will allocate, so the inference process's memory is bounded
as a whole: the model cache holds the models (its own budget), one pool of this kind holds the REST
bodies being received (`reading`, admitted by their Content-Length before a byte is read) and another
everything requests in flight allocate once parsed (`working`: inputs, outputs and their encoding,
activations). A request takes the reading pool, then the working pool, and never the other way round,
so neither pool's holders wait on each other in a cycle.

A request states its bytes before it runs (`services.inference.service` estimates them from the
operation's declared per-row costs). It runs when they fit beside the requests already running, and
waits in arrival order otherwise, so a large request is not starved by a stream of small ones. At most
`max_waiting` requests wait; the next one is refused at once (503, Retry-After) rather than holding its
body in memory for an unbounded time. One larger than the whole budget can never run and is refused by
the caller before it gets here, with the field at fault.

Every `trim_bytes` of finished work, the heap's free pages go back to the OS: torch and the path
tracer's raised malloc thresholds (`workers.render.heap`) would otherwise keep freed arrays resident.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager

from services.inference.errors import Overloaded, QueueFull
from services.inference.metrics import InferenceMetrics
from workers.render.heap import return_freed_memory


class MemoryPool:
    def __init__(
        self, name: str, budget_bytes: int, max_waiting: int, trim_bytes: int, metrics: InferenceMetrics
    ) -> None:
        self.name, self.budget, self.max_waiting = name, budget_bytes, max_waiting
        self.trim_bytes = trim_bytes
        self.used_bytes = metrics.pool_bytes.labels(name)
        self.waiting_requests = metrics.waiting.labels(name)
        self.outcomes = metrics.admission
        self.wait_seconds = metrics.admission_wait.labels(name)
        self.used = 0
        self.released = 0  # bytes finished since the heap was last trimmed
        self.waiting: deque[object] = deque()  # one ticket per waiting request, in arrival order
        self.condition = threading.Condition()

    @contextmanager
    def reserved(self, nbytes: int, timeout_s: float) -> Iterator[None]:
        """Hold `nbytes` (at most the budget) while the block runs; QueueFull when too many wait,
        Overloaded when they do not fit within `timeout_s`."""
        self.acquire(nbytes, timeout_s)
        try:
            yield
        finally:
            self.release(nbytes)

    def try_acquire(self, nbytes: int) -> bool:
        """Take `nbytes` if nobody waits and they fit; never blocks (for an event loop's fast path)."""
        with self.condition:
            if self.waiting or self.used + nbytes > self.budget:
                return False
            self._take(nbytes)
            return True

    def acquire(self, nbytes: int, timeout_s: float) -> None:
        if self.try_acquire(nbytes):
            return
        with self.condition:
            if len(self.waiting) >= self.max_waiting:
                self.outcomes.labels(self.name, "queue_full").inc()
                raise QueueFull(f"{len(self.waiting)} requests already wait for {self.name} memory; retry")
            ticket = object()
            self.waiting.append(ticket)
            self.waiting_requests.set(len(self.waiting))
            start = time.monotonic()
            try:
                admitted = self.condition.wait_for(
                    lambda: self.waiting[0] is ticket and self.used + nbytes <= self.budget, timeout_s
                )
            finally:
                self.waiting.remove(ticket)
                self.waiting_requests.set(len(self.waiting))
                self.condition.notify_all()  # the next in line may fit now
            if not admitted:
                self.outcomes.labels(self.name, "timeout").inc()
                raise Overloaded(f"no {self.name} memory freed within {timeout_s} s; the service is busy")
            self.wait_seconds.observe(time.monotonic() - start)
            self._take(nbytes)

    def _take(self, nbytes: int) -> None:
        self.used += nbytes
        self.outcomes.labels(self.name, "admitted").inc()
        self.used_bytes.set(self.used)

    def release(self, nbytes: int) -> None:
        with self.condition:
            self.used -= nbytes
            self.released += nbytes
            trim = self.released >= self.trim_bytes
            if trim:
                self.released = 0
            self.used_bytes.set(self.used)
            self.condition.notify_all()
        if trim:  # outside the lock: other requests keep being admitted while the heap is walked
            return_freed_memory()
