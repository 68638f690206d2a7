"""Retries with exponential backoff and jitter for what a later attempt can fix: the server unreachable
(connection refused or reset, a restart in progress) or answering 503 / UNAVAILABLE or 429 (a quota used
up). When the server says how long to wait (`Retry-After`), the wait is at least that, up to
`max_retry_after_s`. Anything else (a bad request, a missing job) fails at once.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TypeVar

from neuralbake_client.errors import RETRYABLE

T = TypeVar("T")


@dataclass(frozen=True)
class Retry:
    attempts: int = 4  # tries in all (1: no retries)
    backoff_s: float = 0.25  # wait before the second try; doubles after each further failure
    max_backoff_s: float = 4.0
    max_retry_after_s: float = 60.0  # a longer Retry-After is the caller's to wait for, not a retry's

    def delays(self) -> Iterator[float]:
        """The waits between tries: jittered, doubling up to the cap."""
        for attempt in range(self.attempts - 1):
            yield random.uniform(0.5, 1.0) * min(self.max_backoff_s, self.backoff_s * 2**attempt)

    def call(self, operation: Callable[[], T]) -> T:
        for delay in self.delays():
            try:
                return operation()
            except RETRYABLE as error:
                time.sleep(self.wait(delay, error))
        return operation()

    def wait(self, delay: float, error: Exception) -> float:
        """The backoff `delay`, or the server's `Retry-After` when it asks for longer (capped)."""
        asked = getattr(error, "retry_after", None)
        return delay if asked is None else min(self.max_retry_after_s, max(delay, asked))


DEFAULT_RETRY = Retry()
