"""Inference service throughput: lsnif ray queries through `nbake serve-inference` (binary REST) at 1, 8
and 64 concurrent clients, against calling the kind's `infer` in this process on the same artifact.

Each request carries the same number of rays; the ratio is served queries/s over in-process queries/s
(the issue's target is at least 0.8 at 64 clients, where dynamic batching merges requests). Clients and
server share this machine's cores, so the client side's own HTTP work counts against the server.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import torch

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.bench.common import BenchSection, median_seconds
from tests.integration.test_inference_server import (
    aimed_rays,
    binary_query,
    install_tokens,
    run_and_publish,
    start_server,
)
from tests.unit.test_lsnif_model import instanced_scene
from workers.models.registry import get_inference

RAYS_PER_QUERY = 1024
CLIENTS = (1, 8, 64)
QUERIES_PER_LEVEL = 256
SERVER_THREADS = 1  # the server's default


def _served_level(server, artifact_id: str, clients: int, payloads: list[dict]) -> tuple[float, list[float]]:
    """(queries/s, per-query latencies) of `clients` threads sending `payloads` between them."""
    per_client = [payloads[i::clients] for i in range(clients)]

    def client_loop(mine: list[dict]) -> list[float]:
        latencies = []
        with server.client() as http:
            for arrays in mine:
                start = time.perf_counter()
                response = binary_query(http, artifact_id, arrays)
                latencies.append(time.perf_counter() - start)
                assert response.status_code == 200, response.text
        return latencies

    start = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        latencies = [t for part in pool.map(client_loop, per_client) for t in part]
    return len(payloads) / (time.perf_counter() - start), latencies


def run() -> list[BenchSection]:
    section = BenchSection(f"inference: lsnif queries of {RAYS_PER_QUERY} rays, served vs in-process")
    with tempfile.TemporaryDirectory(prefix="nbake-bench-inference-") as folder:
        data_dir, work = Path(folder) / "data", Path(folder) / "work"
        store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
        artifact = run_and_publish(
            store, work, "lsnif", instanced_scene(), {"min_triangles": 1000, "train": {"steps": 60}}, seed=7
        )
        install_tokens(data_dir)
        payloads = []
        for seed in range(QUERIES_PER_LEVEL):
            origins, directions = aimed_rays(artifact, RAYS_PER_QUERY, seed)
            payloads.append({"origins": origins, "directions": directions})
        torch.set_num_threads(SERVER_THREADS)  # in-process calls get what the server's calls get
        model = artifact.in_process()
        params = get_inference("lsnif").operations["query"].params()
        batch = payloads[: QUERIES_PER_LEVEL // 4]
        seconds = median_seconds(lambda: [model.answer("query", params, p) for p in batch], repeats=3)
        in_process_qps = len(batch) / seconds
        section.add(
            clients="in-process", queries_per_s=in_process_qps, rays_per_s=in_process_qps * RAYS_PER_QUERY
        )
        options = ["--max-wait-ms", "2", "--torch-threads", str(SERVER_THREADS)]
        server = start_server(data_dir, options, artifact)
        try:
            _served_level(server, artifact.artifact_id, 1, payloads[:8])  # load and warm up
            for clients in CLIENTS:
                runs = [_served_level(server, artifact.artifact_id, clients, payloads) for _ in range(3)]
                qps, latencies = sorted(runs, key=lambda r: r[0])[1]  # the median run
                section.add(
                    clients=clients,
                    queries_per_s=qps,
                    rays_per_s=qps * RAYS_PER_QUERY,
                    p50_ms=1000 * statistics.median(latencies),
                    p99_ms=1000 * float(np.percentile(latencies, 99)),
                    ratio_to_in_process=qps / in_process_qps,
                    mean_batch_requests=server.metric("nbake_inference_batch_requests_sum")
                    / max(server.metric("nbake_inference_batch_requests_count"), 1),
                )
        finally:
            server.stop()
    section.notes.append(
        "ratio: served over in-process queries/s in one run, both on 1 torch thread (target >= 0.8 at 64)"
    )
    section.notes.append("mean_batch_requests: cumulative requests per model call since the server started")
    return [section]
