"""Reliability under load: submissions from 200 concurrent clients to 2 API processes sharing a private
PostgreSQL (pg_ctl on a free port), each piece of work submitted 10 times, which must return one job.

Reports requests served, errors, jobs lost (a repeated submission answering another job), latency
percentiles and throughput; the figures are the issue's targets (p99 < 250 ms, >= 300/s, no error).
"""

from __future__ import annotations

import asyncio
import collections
import os
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx

from tests.bench.common import BenchSection
from tests.integration.test_api_server import TOKENS, free_port
from tests.support.postgres import PrivatePostgres

CLIENTS = 200
DISTINCT = 300  # pieces of work
REPEATS = 10  # submissions of each
API_PROCESSES = 2
HEADERS = {"Authorization": f"Bearer {TOKENS['admin']}"}


def run() -> list[BenchSection]:
    with (
        tempfile.TemporaryDirectory(prefix="nbake-bench-rel-", dir="/tmp") as root,
        PrivatePostgres() as postgres,
    ):
        return [submissions(Path(root), postgres.url)]


def submissions(root: Path, database_url: str) -> BenchSection:
    section = BenchSection(
        f"Submissions: {CLIENTS} concurrent clients, {API_PROCESSES} API processes, private PostgreSQL"
    )
    schema = f"nbr_{uuid.uuid4().hex[:12]}"
    ports = [free_port() for _ in range(API_PROCESSES)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), os.environ.get("PYTHONPATH", "")])}
    servers = [
        subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.bench.api_process",
                str(port),
                str(root / f"api{i}"),
                str(root / "store"),
                database_url,
                schema,
            ],
            env=env,
        )
        for i, port in enumerate(ports)
    ]
    try:
        urls = [f"http://127.0.0.1:{port}" for port in ports]
        for url in urls:
            _wait_ready(url, servers)
        result = asyncio.run(_load(urls))
    finally:
        for server in servers:
            server.terminate()
        for server in servers:
            server.wait(60)
    latencies = sorted(result["latencies"])
    section.add(
        requests=len(latencies) + result["errors"],
        errors=result["errors"],
        error_kinds=",".join(f"{k}:{v}" for k, v in sorted(result["error_kinds"].items())) or "-",
        jobs_lost=result["lost"],
        distinct_jobs=result["jobs"],
        p50_ms=1e3 * _percentile(latencies, 0.50),
        p99_ms=1e3 * _percentile(latencies, 0.99),
        max_ms=1e3 * latencies[-1],
        per_s=len(latencies) / result["wall"],
    )
    section.notes.append(
        f"{DISTINCT} render submissions of the quick preset, each sent {REPEATS} times (shuffled) across "
        f"the API processes; a repeat must answer the first one's job. Targets: p99 < 250 ms, >= 300/s."
    )
    return section


def _percentile(values: list[float], q: float) -> float:
    return values[min(len(values) - 1, int(q * (len(values) - 1)))]


def _wait_ready(url: str, servers: list[subprocess.Popen]) -> None:
    deadline = time.monotonic() + 300
    while True:
        try:
            if httpx.get(f"{url}/readyz", timeout=5).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline or any(s.poll() is not None for s in servers):
            raise RuntimeError(f"the API process at {url} did not become ready")
        time.sleep(0.5)


async def _load(urls: list[str]) -> dict:
    import random

    work = [seed for seed in range(DISTINCT) for _ in range(REPEATS)]
    random.Random(0).shuffle(work)
    queue: asyncio.Queue[tuple[int, int]] = asyncio.Queue()
    for index, seed in enumerate(work):
        queue.put_nowait((index, seed))
    latencies, jobs, errors = [], {}, 0
    lost = 0
    kinds: collections.Counter[str] = collections.Counter()
    limits = httpx.Limits(max_connections=CLIENTS, max_keepalive_connections=CLIENTS)
    clients = [httpx.AsyncClient(base_url=u, headers=HEADERS, limits=limits, timeout=120) for u in urls]

    async def client_loop(number: int) -> None:
        nonlocal errors, lost
        http = clients[number % len(clients)]
        while not queue.empty():
            _, seed = queue.get_nowait()
            body = {"kind": "render", "scene": "cornell_box", "preset": "quick", "seed": seed}
            start = time.perf_counter()
            try:
                response = await http.post("/v1/jobs", json=body)
            except httpx.HTTPError as error:
                errors += 1
                kinds[type(error).__name__] += 1
                continue
            if response.status_code not in (200, 201):
                errors += 1
                kinds[str(response.status_code)] += 1
                continue
            latencies.append(time.perf_counter() - start)
            job_id = response.json()["id"]
            if jobs.setdefault(seed, job_id) != job_id:
                lost += 1

    start = time.perf_counter()
    try:
        await asyncio.gather(*(client_loop(n) for n in range(CLIENTS)))
    finally:
        for http in clients:
            await http.aclose()
    return {
        "latencies": latencies,
        "errors": errors,
        "error_kinds": dict(kinds),
        "lost": lost,
        "jobs": len(set(jobs.values())),
        "wall": time.perf_counter() - start,
    }
