"""Streams that stop when their caller does: a stream's work runs only while its call is active (the
client has not cancelled, disconnected or run out of deadline), and the number of streams doing work
(server streams and the client stream of an upload) is exported as `nbake_grpc_active_streams{method}`
beside the service's other metrics.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

import grpc
from prometheus_client import CollectorRegistry, Gauge

from services.jobs.following import POLL_S


class StreamTracker:
    def __init__(self, registry: CollectorRegistry):
        self.active = Gauge(
            "nbake_grpc_active_streams",
            "gRPC streams currently doing work for a caller",
            ["method"],
            registry=registry,
        )

    @contextmanager
    def track(self, method: str) -> Iterator[None]:
        """Count the block as one active stream; the count drops however the block ends."""
        gauge = self.active.labels(method)
        gauge.inc()
        try:
            yield
        finally:
            gauge.dec()


def pause(context: grpc.ServicerContext) -> bool:
    """Wait up to one poll interval (less if the deadline is nearer); False once the call is over."""
    remaining = context.time_remaining()
    time.sleep(max(0.0, min(POLL_S, remaining if remaining is not None else POLL_S)))
    return context.is_active()
