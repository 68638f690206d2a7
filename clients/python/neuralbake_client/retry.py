"""Retries with exponential backoff and jitter for what a later attempt can fix: the server unreachable
(connection refused or reset, a restart in progress) or answering 503 / UNAVAILABLE. Anything else
(a bad request, a missing job) fails at once.
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

    def delays(self) -> Iterator[float]:
        """The waits between tries: jittered, doubling up to the cap."""
        for attempt in range(self.attempts - 1):
            yield random.uniform(0.5, 1.0) * min(self.max_backoff_s, self.backoff_s * 2**attempt)

    def call(self, operation: Callable[[], T]) -> T:
        for delay in self.delays():
            try:
                return operation()
            except RETRYABLE:
                time.sleep(delay)
        return operation()


DEFAULT_RETRY = Retry()
