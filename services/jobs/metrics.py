"""Prometheus metrics of one service instance (its own registry, so several can share a process)."""

from __future__ import annotations

from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import GaugeMetricFamily

from services.jobs.states import JobState

DURATION_BUCKETS = (0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600, 1800, 3600, 4 * 3600, 24 * 3600)


class _JobsByState:
    """Counted from the database at scrape time, so every replica reports the same truth."""

    def __init__(self, count: Callable[[], dict[str, int]]):
        self.count = count

    def collect(self):
        family = GaugeMetricFamily("nbake_jobs", "Jobs by state.", labels=["state"])
        counts = self.count()
        for state in JobState:
            family.add_metric([state.value], counts.get(state.value, 0))
        yield family


class ServiceMetrics:
    def __init__(self, count_by_state: Callable[[], dict[str, int]]):
        self.registry = CollectorRegistry()
        self.registry.register(_JobsByState(count_by_state))
        self.submissions = Counter(
            "nbake_job_submissions",
            "Job submissions, by whether they created a job.",
            ["created"],
            registry=self.registry,
        )
        self.queue_wait = Histogram(
            "nbake_job_queue_wait_seconds",
            "Time from submission to start.",
            ["kind"],
            buckets=DURATION_BUCKETS,
            registry=self.registry,
        )
        self.duration = Histogram(
            "nbake_job_duration_seconds",
            "Time from start to a final state.",
            ["kind", "state"],
            buckets=DURATION_BUCKETS,
            registry=self.registry,
        )
        self.samples_per_s = Gauge(
            "nbake_job_samples_per_second",
            "Latest samples/s reported by a running job.",
            ["job_id", "kind"],
            registry=self.registry,
        )
        self.sse_streams = Gauge(
            "nbake_sse_active_streams",
            "Server-Sent Event streams currently following a job (back to zero once their clients leave).",
            registry=self.registry,
        )
