"""The job server's own cost: submission latency and throughput under 200 concurrent submissions (SQLite
and PostgreSQL), and the overhead of running a `render` as a job against calling the renderer directly.

Submissions go to an API-only server (no scheduler), so the figures are the API and database path alone.
The overhead ratio is the wall time from POST to SUCCEEDED (queueing, Ray actors, checkpoints, publishing
the artifact) over the direct render's, in the same run on the same cores.
"""

from __future__ import annotations

import asyncio
import os
import statistics
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import ray

from tests.bench.common import BenchSection
from tests.integration.test_api_server import (
    TOKENS,
    DatabaseChoice,
    ServerThread,
    drop_schema,
    settings_for,
    wait_for,
)
from workers.models.registry import get_kind
from workers.render.render import render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SUBMISSIONS = 200
HEADERS = {"Authorization": f"Bearer {TOKENS['admin']}"}
RENDER = {"kind": "render", "scene": "cornell_box", "preset": "default"}  # 256x256, 256 spp: ~30 s here


def run() -> list[BenchSection]:
    with tempfile.TemporaryDirectory(prefix="nbake-bench-", dir="/tmp") as root:
        ray.init(num_cpus=2, include_dashboard=False, _temp_dir=f"{root}/ray", log_to_driver=False)
        try:
            return [submissions(Path(root)), overhead(Path(root))]
        finally:
            ray.shutdown()


def submissions(root: Path) -> BenchSection:
    section = BenchSection(f"Job submission: {SUBMISSIONS} concurrent POST /v1/jobs (API only)")
    databases = [DatabaseChoice("sqlite", None)]
    if url := os.environ.get("NBAKE_TEST_POSTGRES_URL"):
        databases.append(DatabaseChoice("postgresql", url, f"nbb_{uuid.uuid4().hex[:12]}"))
    else:
        section.notes.append("PostgreSQL skipped: NBAKE_TEST_POSTGRES_URL is not set")
    for database in databases:
        settings = settings_for(root / f"submit-{database.name}", database, scheduling=False)
        try:
            with ServerThread(settings) as server:
                latencies, wall = asyncio.run(_submit_all(server.url))
                batch_s = _submit_batch(server.url)
        finally:
            if database.schema:
                drop_schema(database.url, database.schema)
        latencies.sort()
        section.add(
            database=database.name,
            how=f"{SUBMISSIONS} POST /v1/jobs at once",
            p50_ms=1e3 * statistics.median(latencies),
            p99_ms=1e3 * latencies[int(0.99 * (len(latencies) - 1))],
            max_ms=1e3 * latencies[-1],
            submissions_per_s=SUBMISSIONS / wall,
        )
        section.add(
            database=database.name,
            how=f"one POST /v1/jobs:batch of {SUBMISSIONS}",
            max_ms=1e3 * batch_s,
            submissions_per_s=SUBMISSIONS / batch_s,
        )
    section.notes.append(
        "each submission validates the config, plans the render and writes job, key and event rows; every "
        "job is distinct new work (its own seed); the batch's jobs are new too (seeds after the singles')"
    )
    return section


def _submit_batch(url: str) -> float:
    """Seconds to answer one batch of `SUBMISSIONS` distinct new jobs, all or nothing in one transaction."""
    jobs = [{**RENDER, "preset": "quick", "seed": SUBMISSIONS + seed} for seed in range(SUBMISSIONS)]
    with httpx.Client(base_url=url, headers=HEADERS, timeout=120) as client:
        start = time.perf_counter()
        response = client.post("/v1/jobs:batch", json={"jobs": jobs})
        seconds = time.perf_counter() - start
    assert response.status_code == 200 and all(item["created"] for item in response.json()["items"])
    return seconds


async def _submit_all(url: str) -> tuple[list[float], float]:
    limits = httpx.Limits(max_connections=SUBMISSIONS, max_keepalive_connections=SUBMISSIONS)
    async with httpx.AsyncClient(base_url=url, headers=HEADERS, limits=limits, timeout=120) as client:

        async def one(seed: int) -> float:
            start = time.perf_counter()
            response = await client.post("/v1/jobs", json={**RENDER, "preset": "quick", "seed": seed})
            assert response.status_code == 201, response.text
            return time.perf_counter() - start

        start = time.perf_counter()
        latencies = await asyncio.gather(*(one(seed) for seed in range(SUBMISSIONS)))
        return list(latencies), time.perf_counter() - start


def overhead(root: Path) -> BenchSection:
    section = BenchSection("Service overhead: a render job vs the renderer called directly")
    settings = settings_for(root / "overhead", DatabaseChoice("sqlite", None))
    with (
        ServerThread(settings) as server,
        httpx.Client(base_url=server.url, headers=HEADERS, timeout=60) as client,
    ):
        start = time.perf_counter()
        job = client.post("/v1/jobs", json=RENDER).json()
        done = wait_for(client, job["id"], {"SUCCEEDED", "FAILED"}, timeout=1800)
        service_s = time.perf_counter() - start
    assert done["state"] == "SUCCEEDED", done["error"]
    kind = get_kind("render")
    config = kind.resolve_config("default", {})
    start = time.perf_counter()
    render(
        compile_scene(get_builtin("cornell_box")), config.settings(seed=0).model_copy(update={"threads": 2})
    )
    direct_s = time.perf_counter() - start
    section.add(
        render=f"cornell_box {config.width}x{config.height} {config.spp} spp",
        direct_s=direct_s,
        service_s=service_s,
        ratio=service_s / direct_s,
    )
    section.notes.append("one run each (a 30-second render); target ratio < 1.2")
    return section
