"""The inference service's memory is bounded as a whole, not only its model cache: many concurrent mixed
queries through a real `nbake serve-inference` keep the server process's RSS (its own /proc status, so
torch, batching, decoding and encoding all count) below idle + cache budget + reading and working
budgets + a stated allowance; a query that could never fit the working budget is refused with a 413
naming its field, over REST and gRPC, before anything is allocated for it."""

from __future__ import annotations

import random
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import grpc
import numpy as np
import pytest
from neuralbake.v1 import inference_pb2, inference_pb2_grpc

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.integration.test_api_server import TOKENS
from tests.integration.test_inference_server import (
    Server,
    aimed_rays,
    binary_query,
    install_tokens,
    run_and_publish,
    start_server,
)
from tests.unit.test_lsnif_model import instanced_scene
from workers.scene.generators.builtin import BUILTIN_SCENES

MB = 1 << 20
WORKING_BYTES, READING_BYTES = 48 * MB, 16 * MB
CHUNK_ROWS = 2048  # small, so a request's estimate is mostly its own arrays, not one chunk's activations
CLIENTS = 16
MIXED_PER_CLIENT = 3
# Rays as float32, which the service converts to float64, aimed away from every object (cheap to answer):
# about 36 MB of working memory each, so one runs at a time; with nothing admitting them, every client's
# body, converted rays and answer are alive at once (about 25 MB each).
BIG_RAYS = 150_000
REFUSED_RAYS = 250_000  # within --max-rows (1M), but about 56 MB: more than the whole working budget
UNREAD_RAYS = 400_000  # a 9.6 MB body, which takes 19 MB to receive: more than the whole reading budget
# What the bound allows beyond the three budgets: the allocator's slack (freed blocks between trims,
# per-thread arenas) and the HTTP and thread machinery. `idle` is measured once both models are loaded
# and have answered a small query (their kernels and torch's operator tables are then resident).
FIXED_ALLOWANCE = 32 * MB


def rss(pid: int, key: str = "VmRSS") -> int:
    """Bytes of the process's resident set (`VmRSS`) or of its peak (`VmHWM`), from /proc/<pid>/status."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {key} for {pid}")


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[tuple[Server, int]]:
    data_dir, work = tmp_path_factory.mktemp("inference-memory"), tmp_path_factory.mktemp("jobs")
    store = ArtifactStore(BlobStore(str(data_dir / "store")), str(data_dir / "store"))
    lsnif = run_and_publish(
        store, work, "lsnif", instanced_scene(), {"min_triangles": 1000, "train": {"steps": 60}}, seed=7
    )
    cornell = BUILTIN_SCENES["cornell_box"]()
    render = run_and_publish(store, work, "render", cornell, {"samplers": 0, "width": 64, "height": 48}, 1)
    install_tokens(data_dir)
    cache_budget = lsnif.in_process().nbytes + render.in_process().nbytes  # both stay loaded
    options = ["--memory-bytes", str(cache_budget), "--working-bytes", str(WORKING_BYTES)]
    options += ["--reading-bytes", str(READING_BYTES), "--chunk-rows", str(CHUNK_ROWS)]
    running = start_server(data_dir, [*options, "--max-wait-ms", "2"], lsnif, render)
    try:
        yield running, cache_budget
    finally:
        running.stop()


def _mixed_requests(server: Server) -> list[tuple[str, dict, dict]]:
    """(artifact id, arrays, params): ray queries from tiny to large, pixel queries, whole layers."""
    requests = []
    for rays in (16, 4096):
        origins, directions = aimed_rays(server.lsnif, rays, seed=rays)
        requests.append((server.lsnif.artifact_id, {"origins": origins, "directions": directions}, {}))
    requests.append((server.lsnif.artifact_id, _rays_away(BIG_RAYS), {}))
    rng = np.random.default_rng(0)
    for pixels in (1, 3072, 100_000):
        xy = np.stack([rng.integers(64, size=pixels), rng.integers(48, size=pixels)], 1).astype(np.int64)
        requests.append((server.render.artifact_id, {"pixels": xy}, {"layers": ["image", "depth"]}))
    requests.append((server.render.artifact_id, {}, {}))
    return requests


def _rays_away(n: int) -> dict[str, np.ndarray]:
    """float32 rays from far out, pointing further out: the broad phase answers them without a network."""
    rng = np.random.default_rng(n)
    origins = (1000 + rng.random((n, 3))).astype(np.float32)
    return {"origins": origins, "directions": np.ones((n, 3), np.float32)}


def _ask(server: Server, requests: list[tuple[str, dict, dict]]) -> list[int]:
    with server.client() as http:
        return [binary_query(http, *request).status_code for request in requests]


def test_rss_stays_within_idle_plus_cache_plus_working_budget_under_concurrent_mixed_queries(server):
    running, cache_budget = server
    pid = running.process.pid
    requests = _mixed_requests(running)
    assert _ask(running, [requests[0], requests[3]]) == [200, 200]  # both models loaded, their code warm
    idle = rss(pid)
    bound = idle + cache_budget + READING_BYTES + WORKING_BYTES + FIXED_ALLOWANCE
    big, mixed = requests[2], requests[:2] + requests[3:]

    def client(number: int) -> list[int]:
        pick = random.Random(number)
        return _ask(running, [big, *(pick.choice(mixed) for _ in range(MIXED_PER_CLIENT))])

    Path(f"/proc/{pid}/clear_refs").write_text("5")  # the peak from here on
    with ThreadPoolExecutor(CLIENTS) as pool:
        statuses = [s for part in pool.map(client, range(CLIENTS)) for s in part]
    peak = rss(pid, "VmHWM")  # the kernel's own high-water mark: no sample can miss the peak
    assert statuses == [200] * len(statuses)
    assert running.metric("nbake_inference_admission_total", pool="working", outcome="admitted") >= len(
        statuses
    )

    assert peak < bound, (
        f"peak RSS {peak / MB:.0f} MB over the bound {bound / MB:.0f} MB: idle {idle / MB:.0f} + cache "
        f"{cache_budget / MB:.0f} + reading {READING_BYTES / MB:.0f} + working {WORKING_BYTES / MB:.0f} + "
        f"allowance {FIXED_ALLOWANCE / MB:.0f}"
    )


def test_a_query_larger_than_the_working_budget_is_refused_naming_the_field(server):
    running, _ = server
    with running.client() as http:
        refused = binary_query(http, running.lsnif.artifact_id, _rays_away(REFUSED_RAYS))
        unread = binary_query(http, running.lsnif.artifact_id, _rays_away(UNREAD_RAYS))
    assert refused.status_code == 413, refused.text
    assert refused.headers["content-type"] == "application/problem+json"
    problem = refused.json()
    assert problem["field"] == "arrays.origins"
    assert f"{WORKING_BYTES:,}" in problem["detail"] and "NBAKE_INFERENCE_WORKING_BYTES" in problem["detail"]
    assert unread.status_code == 413 and unread.json()["field"] == "body", unread.text
    assert f"{READING_BYTES:,}" in unread.json()["detail"]
    with running.client() as http:  # a 0-d array reaches the estimate before the shape check: still its 422
        scalar = {"origins": np.array(1.0), "directions": np.array(1.0)}
        shapeless = binary_query(http, running.lsnif.artifact_id, scalar)
    assert shapeless.status_code == 422 and shapeless.json()["field"] == "arrays.origins", shapeless.text

    origins, directions = (a.astype(np.float64) for a in _rays_away(REFUSED_RAYS).values())

    request = inference_pb2.QueryRequest(
        artifact_id=running.lsnif.artifact_id,
        arrays=[
            inference_pb2.Array(name=name, dtype="float64", shape=list(a.shape), data=a.tobytes())
            for name, a in (("origins", origins), ("directions", directions))
        ],
    )
    options = [("grpc.max_send_message_length", 64 * MB)]
    with grpc.insecure_channel(running.grpc_target, options=options) as channel:
        stub = inference_pb2_grpc.InferenceServiceStub(channel)
        with pytest.raises(grpc.RpcError) as error:
            stub.Query(request, metadata=(("authorization", f"Bearer {TOKENS['read']}"),), timeout=60)
    assert error.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    assert "arrays.origins" in error.value.details() and f"{WORKING_BYTES:,}" in error.value.details()
