"""Scale-out figures: a `lod` quick job on one Ray node against two, and the artifact store's throughput
on `s3://` against `file://` for a 100 MB artifact.

Nodes: the machine's two cores as one node of 2 CPUs, or as two nodes of 1 CPU each (the second in its
own mount namespace, as in `tests/integration/test_scaleout_cluster.py`); the job asks for 2 samplers,
so on two nodes one sampler runs on each and every batch of the other crosses between the nodes' object
stores. Equal cores make the ratio the cost of distributing, not a speed-up. The S3 server is moto's (an
emulator written in Python, on the same cores), so its figures bound the protocol path, not AWS.
"""

from __future__ import annotations

import os
import shutil
import statistics
import tempfile
import uuid
from datetime import datetime
from pathlib import Path

import httpx

from tests.bench.common import BenchSection, median_seconds
from tests.integration.test_api_server import TOKENS, TOKENS_ENV, drop_schema, events, postgres_url
from tests.support.cluster import LocalCluster, ServeReplica
from tests.support.s3 import moto_s3

ARTIFACT_BYTES = 100 << 20
REPEATS = 3
JOB_RUNS = 2
REPO = Path(__file__).resolve().parents[2]
LOD_JOB = {"kind": "lod", "scene": "menger_sponge", "preset": "quick", "config": {"samplers": 2}}


def run() -> list[BenchSection]:
    with moto_s3() as s3:
        return [store_throughput(s3), lod_on_nodes(s3)]


def store_throughput(s3) -> BenchSection:
    from services.artifacts.store import BlobStore

    section = BenchSection("artifact store: a 100 MB artifact in and out (put_file, verified download)")
    with tempfile.TemporaryDirectory(prefix="nbake-bench-") as root:
        source = Path(root) / "artifact.bin"
        source.write_bytes(os.urandom(ARTIFACT_BYTES))
        results = {}
        for name, url in (("file://", f"file://{root}/store"), ("s3://", f"s3://{s3.bucket()}/nbake")):

            def put(url=url) -> None:
                store = BlobStore(url)
                digest = store.put_file(source)
                store.delete(digest)  # the next put writes again instead of finding it stored

            put_s = median_seconds(put, repeats=REPEATS, warmup=0)
            store = BlobStore(url)
            digest = store.put_file(source)
            get_s = median_seconds(
                lambda s=store, d=digest: s.download(d, Path(root) / "out.bin"), REPEATS, 0
            )
            results[name] = (put_s, get_s)
            mb = ARTIFACT_BYTES / 1e6
            section.add(
                store=name, put_s=put_s, put_MB_s=mb / put_s, download_s=get_s, download_MB_s=mb / get_s
            )
        section.notes.append(
            f"s3/file time ratio: put {results['s3://'][0] / results['file://'][0]:.3g}x, "
            f"download {results['s3://'][1] / results['file://'][1]:.3g}x (medians of {REPEATS})"
        )
    return section


def lod_on_nodes(s3) -> BenchSection:
    section = BenchSection("lod quick job (2 samplers) on 1 node of 2 CPUs vs 2 nodes of 1 CPU")
    database_url = postgres_url()
    figures = {}
    for nodes in (1, 2):
        root = Path(tempfile.mkdtemp(prefix="nbb-", dir="/tmp"))
        (root / "server").mkdir()
        env = {**s3.env, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"}
        cluster = LocalCluster(root / "nodes", env)
        schema = f"nbb_{uuid.uuid4().hex[:12]}"
        replica = None
        try:
            head = cluster.start_head(cpus=2 if nodes == 1 else 1)
            if nodes == 2:
                cluster.add_node("worker", cpus=1, hidden=(root / "server", head.folder))
            replica = ServeReplica(
                root / "server" / "api",
                {
                    **cluster.client_env,
                    "NBAKE_DATABASE_URL": database_url,
                    "NBAKE_DATABASE_SCHEMA": schema,
                    "NBAKE_STORE_URL": f"s3://{s3.bucket()}/nbake",
                    "NBAKE_TOKENS": TOKENS_ENV,
                },
            ).start()
            walls, rates = [], []
            with httpx.Client(
                base_url=replica.url, headers={"Authorization": f"Bearer {TOKENS['admin']}"}, timeout=60
            ) as client:
                for seed in range(JOB_RUNS + 1):  # the first run warms the nodes' workers up: not counted
                    job = client.post("/v1/jobs", json={**LOD_JOB, "seed": seed}).json()
                    job_events = events(client, job["id"], timeout=1800)
                    assert job_events[-1]["data"]["state"] == "SUCCEEDED", job_events[-1]
                    view = client.get(f"/v1/jobs/{job['id']}").json()
                    if seed == 0:
                        continue
                    started, finished = (
                        datetime.fromisoformat(view[k]) for k in ("started_at", "finished_at")
                    )
                    walls.append((finished - started).total_seconds())
                    rates += [
                        e["data"]["samples_per_s"] for e in job_events if e["data"].get("samples_per_s")
                    ]
            figures[nodes] = (statistics.median(walls), statistics.median(rates))
            section.add(nodes=nodes, wall_s=figures[nodes][0], samples_per_s=figures[nodes][1], runs=JOB_RUNS)
        finally:
            if replica is not None:
                replica.stop()
            cluster.stop()
            drop_schema(database_url, schema)
            shutil.rmtree(root, ignore_errors=True)
    section.notes.append(
        f"2 nodes / 1 node: wall time {figures[2][0] / figures[1][0]:.3g}x, "
        f"samples/s {figures[2][1] / figures[1][1]:.3g}x (equal cores: the cost of distributing)"
    )
    return section
