"""Prometheus figures of one inference server: requests by operation and status, latency, how well
dynamic batching merges (rows and requests per model call), how the model cache behaves, and the
working memory of requests in flight (reserved bytes, waiting requests, admission outcomes)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

ROW_BUCKETS = (1, 16, 256, 1024, 4096, 16384, 65536, 262144, 1 << 20)
REQUEST_BUCKETS = (1, 2, 4, 8, 16, 32, 64, 128)


class InferenceMetrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "nbake_inference_requests",
            "Requests by operation and HTTP-style status",
            ["operation", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "nbake_inference_latency_seconds",
            "Time from a request's arrival to its answer",
            ["operation"],
            registry=self.registry,
        )
        self.batch_rows = Histogram(
            "nbake_inference_batch_rows", "Rows per model call", buckets=ROW_BUCKETS, registry=self.registry
        )
        self.batch_requests = Histogram(
            "nbake_inference_batch_requests",
            "Requests merged into one model call",
            buckets=REQUEST_BUCKETS,
            registry=self.registry,
        )
        self.cache = Counter(
            "nbake_inference_cache",
            "Model cache lookups (hit, miss) and evictions",
            ["event"],
            registry=self.registry,
        )
        self.loaded_bytes = Gauge(
            "nbake_inference_loaded_bytes", "Bytes of loaded models", registry=self.registry
        )
        self.loaded_models = Gauge("nbake_inference_loaded_models", "Loaded models", registry=self.registry)
        self.pool_bytes = Gauge(
            "nbake_inference_reserved_bytes",
            "Memory reserved by requests in flight, by pool (reading bodies, working)",
            ["pool"],
            registry=self.registry,
        )
        self.waiting = Gauge(
            "nbake_inference_waiting_requests",
            "Requests waiting for memory, by pool",
            ["pool"],
            registry=self.registry,
        )
        self.admission = Counter(
            "nbake_inference_admission",
            "Admission outcomes by pool (admitted, too_large, queue_full, timeout)",
            ["pool", "outcome"],
            registry=self.registry,
        )
        self.admission_wait = Histogram(
            "nbake_inference_admission_wait_seconds",
            "Time a request waited for memory, by pool",
            ["pool"],
            registry=self.registry,
        )
