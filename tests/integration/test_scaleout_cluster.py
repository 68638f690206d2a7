"""Scale-out as a real cluster on one machine: a Ray head and a second Ray node (each `ray start` in its
own process tree and folders; the second in a mount namespace of its own, with a private tmpfs over the
server's data dir and the head's folder), `nbake serve` joining it through `RAY_ADDRESS`, PostgreSQL (a
schema per deployment) and an S3 bucket (moto's server: the one emulated part). Nothing is shared between
the server and the second node but the network: scenes, checkpoints and outputs go through the bucket.

The head has 1 CPU and the second node 2, so a job reserving 2 sampler CPUs (reserved as one packed
gang) places its samplers on the second node.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import socket
import tempfile
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import fsspec
import httpx
import pytest

from tests.integration.test_api_server import (
    TOKENS,
    TOKENS_ENV,
    drop_schema,
    events,
    postgres_url,
    submit,
    wait_for,
)
from tests.integration.test_lod_uploaded_asset import blob_obj, scene_yaml
from tests.support.cluster import LocalCluster, RayNode, ServeReplica
from tests.support.s3 import S3Server, moto_s3

REPO = Path(__file__).resolve().parents[2]
# A two-node cluster, PostgreSQL and an S3 server cost about two minutes before any job: the whole module
# runs with `make test-all`; the default suite keeps the store-only data path (test_store_data_path.py).
pytestmark = [pytest.mark.timeout(1200), pytest.mark.slow]
TEARDOWN_GRACE_S = 5.0  # a server stopped for good needs no graceful drain


@dataclass
class ScaleOut:
    root: Path
    cluster: LocalCluster
    head: RayNode
    worker: RayNode
    s3: S3Server
    store_url: str
    database_url: str

    @property
    def server_root(self) -> Path:
        return self.root / "server"  # what the second node cannot see

    def replica(self, name: str, schema: str, max_running: int = 2) -> ServeReplica:
        env = {
            **self.cluster.client_env,
            "NBAKE_DATABASE_URL": self.database_url,
            "NBAKE_DATABASE_SCHEMA": schema,
            "NBAKE_STORE_URL": self.store_url,
            "NBAKE_TOKENS": TOKENS_ENV,
            "NBAKE_MAX_RUNNING": str(max_running),
        }
        return ServeReplica(self.server_root / name, env, log_name=name)

    def blob_in_bucket(self, digest: str) -> bytes:
        hex_digest = digest.removeprefix("sha256:")
        return fsspec.filesystem("s3").cat_file(
            f"{self.store_url}/blobs/sha256/{hex_digest[:2]}/{hex_digest[2:]}"
        )

    def restart_worker(self) -> None:
        """A fresh second node (after a test killed one), hidden from the server as before."""
        self.worker = self.cluster.add_node(
            f"worker-{uuid.uuid4().hex[:6]}", cpus=2, hidden=(self.server_root, self.head.folder)
        )


@pytest.fixture(scope="module")
def scaleout() -> Iterator[ScaleOut]:
    database_url = postgres_url()
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("the second node's own mount namespace needs root and unshare (CI runs as root)")
    root = Path(tempfile.mkdtemp(prefix="nbc-", dir="/tmp"))  # short: Ray's socket paths live below it
    (root / "server").mkdir()
    try:
        with moto_s3() as s3:
            store_url = f"s3://{s3.bucket()}/nbake"
            env = {**s3.env, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"}
            cluster = LocalCluster(root / "nodes", env)
            try:
                head = cluster.start_head(cpus=1)
                worker = cluster.add_node("worker", cpus=2, hidden=(root / "server", head.folder))
                yield ScaleOut(root, cluster, head, worker, s3, store_url, database_url)
            finally:
                cluster.stop()
    finally:
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(scope="module")
def api(scaleout) -> Iterator[ServeReplica]:
    """One `nbake serve` on the cluster for the module's jobs, on a schema of its own."""
    schema = f"nbc_{uuid.uuid4().hex[:12]}"
    replica = scaleout.replica("api", schema).start()
    try:
        yield replica
    finally:
        replica.stop(grace_s=TEARDOWN_GRACE_S)
        drop_schema(scaleout.database_url, schema)


def client_of(replica: ServeReplica) -> httpx.Client:
    return httpx.Client(
        base_url=replica.url, headers={"Authorization": f"Bearer {TOKENS['admin']}"}, timeout=60
    )


def upload_blob_scene(client: httpx.Client) -> str:
    files = [("scene.yaml", scene_yaml()), ("meshes/blob.obj", blob_obj())]
    response = client.post("/v1/assets", files=[("files", (name, io.BytesIO(data))) for name, data in files])
    assert response.status_code == 201, response.text
    return response.json()["asset_id"]


def sampler_actors_on(node: RayNode) -> int:
    """Sampler actors that ran on `node`: Ray names each worker's actor class in the node's own logs."""
    logs = node.folder / "temp" / "session_latest" / "logs"
    return sum(b":actor_name:SamplerActor" in path.read_bytes() for path in logs.glob("worker-*.out"))


def assert_artifact_in_bucket(scaleout: ScaleOut, client: httpx.Client, job: dict) -> dict:
    """Every file of the job's artifact is a blob in the bucket, byte-equal to what the API serves."""
    manifest = client.get(f"/v1/artifacts/{job['artifact_id']}").json()
    for entry in manifest["files"]:
        served = client.get(f"/v1/artifacts/{job['artifact_id']}/files/{entry['name']}")
        assert served.status_code == 200, served.text
        assert scaleout.blob_in_bucket(entry["digest"]) == served.content, entry["name"]
    return manifest


def follow_until(client: httpx.Client, job_id: str, done, timeout: float = 900) -> list[dict]:
    """Follow the job's event stream until `done(events)` holds (then leave it); the events so far."""
    parsed, fields, deadline = [], {}, time.monotonic() + timeout
    with client.stream("GET", f"/v1/jobs/{job_id}/events", timeout=60) as response:
        for line in response.iter_lines():  # a keep-alive comment arrives at least every 15 s
            assert time.monotonic() < deadline, f"not reached within {timeout} s: {parsed}"
            if line == "" and "data" in fields:
                parsed.append(json.loads(fields["data"]))
                if done(parsed):
                    return parsed
                fields = {}
            elif line and not line.startswith(":"):
                name, _, value = line.partition(":")
                fields[name] = value.removeprefix(" ")
    raise AssertionError(f"the stream ended first: {parsed}")


def steps(job_events: list[dict]) -> list[int]:
    return [e["data"]["step"] for e in job_events if e["type"] == "progress"]


def progress_after(job_events: list[dict], marker: str) -> list[int]:
    """Steps of the progress events after the last log event whose message contains `marker`."""
    last = max(i for i, e in enumerate(job_events) if marker in str(e["data"].get("message", "")))
    return [e["data"]["step"] for e in job_events[last:] if e["type"] == "progress"]


# ---------------------------------------------------------------------------------------------- tests


def test_a_job_with_its_samplers_on_the_second_node_reads_the_scene_from_the_bucket(scaleout, api):
    server_file = scaleout.server_root / "api" / "visible-to-the-server-only"
    server_file.write_text("only the server's machine sees this")
    assert scaleout.head.sees(server_file) and not scaleout.worker.sees(server_file)
    with client_of(api) as client:
        asset_id = upload_blob_scene(client)
        job = submit(client, kind="render", scene=asset_id, preset="quick", config={"samplers": 2})
        final = events(client, job["id"], timeout=600)[-1]["data"]
        assert final["state"] == "SUCCEEDED", final
        job = client.get(f"/v1/jobs/{job['id']}").json()
        manifest = assert_artifact_in_bucket(scaleout, client, job)
    assert {"image.exr", "preview.png", "report.json"} <= {f["name"] for f in manifest["files"]}
    assert sampler_actors_on(scaleout.worker) >= 1
    fetched = scaleout.worker.scene_cache / asset_id.removeprefix("sha256:")
    assert (fetched / "meshes" / "blob.obj").read_bytes() == blob_obj()  # by digest, from the bucket
    assert not (scaleout.server_root / "api" / "store").exists()  # the server keeps no artifact itself


@pytest.mark.parametrize(
    ("kind", "scene", "config"),
    [  # slow: the render above is the default suite's job through the cluster
        pytest.param("lod", "menger_sponge", {"samplers": 1}, marks=pytest.mark.slow),
        pytest.param("lsnif", "thin_walls", {}, marks=pytest.mark.slow),
    ],
)
def test_a_quick_job_of_each_training_kind_succeeds_with_its_artifact_in_the_bucket(
    scaleout, api, kind, scene, config
):
    with client_of(api) as client:
        job = submit(client, kind=kind, scene=scene, preset="quick", config=config)
        final = events(client, job["id"], timeout=900)[-1]["data"]
        assert final["state"] == "SUCCEEDED", final
        job = client.get(f"/v1/jobs/{job['id']}").json()
        manifest = assert_artifact_in_bucket(scaleout, client, job)
    assert manifest["kind"] == kind and manifest["files"]


@pytest.mark.slow
def test_restarting_nbake_serve_mid_job_resumes_it_from_the_store(scaleout, api):
    config = {"samplers": 1, "width": 64, "height": 64, "tile_size": 32, "spp": 256}  # 4 passes of 64
    with client_of(api) as client:
        job = submit(client, kind="render", scene="cornell_box", preset="quick", config=config)
        follow_until(client, job["id"], lambda seen: steps(seen))  # a pass and its checkpoint are done
    api.stop()
    api.start()
    with client_of(api) as client:
        job_events = events(client, job["id"], timeout=600)
    assert job_events[-1]["data"]["state"] == "SUCCEEDED", job_events[-1]
    messages = [str(e["data"].get("message", "")) for e in job_events]
    assert any("resuming from its checkpoint" in m for m in messages)
    assert any("resuming from the checkpoint after pass" in m for m in messages), messages


@pytest.mark.slow
def test_losing_the_second_node_mid_job_finishes_the_job_on_the_head_from_its_checkpoint(scaleout, api):
    """SIGKILL of the second node's raylet while it holds the job's samplers: the job is retried on the
    head alone, resumes from its last checkpoint in the bucket (not from step 0), and succeeds."""
    with client_of(api) as client:
        asset_id = upload_blob_scene(client)
        job = submit(client, kind="lod", scene=asset_id, preset="quick", config={"samplers": 2})
        follow_until(client, job["id"], lambda seen: steps(seen) and steps(seen)[-1] > 50)  # checkpointed
        assert sampler_actors_on(scaleout.worker) >= 1
        scaleout.worker.kill_raylet()
        try:
            job_events = events(client, job["id"], timeout=900)
        finally:
            scaleout.restart_worker()
    assert job_events[-1]["data"]["state"] == "SUCCEEDED", job_events[-1]
    resumed = progress_after(job_events, "retrying")
    assert resumed and resumed[0] > 50, resumed  # from the checkpoint at step 50, nothing lost
    assert sampler_actors_on(scaleout.head) >= 1


def test_two_api_replicas_share_jobs_and_run_each_exactly_once(scaleout, api):
    """A second `nbake serve` replica on the module server's PostgreSQL schema and bucket: a job submitted
    to one is visible, followable and cancellable through the other, and of jobs submitted to both, each
    is started by exactly one scheduler."""
    second = scaleout.replica("second", api.env["NBAKE_DATABASE_SCHEMA"], max_running=1)
    try:
        second.start()
        with client_of(api) as one, client_of(second) as other:
            long_render = {"samplers": 0, "spp": 4096}
            job = submit(one, kind="render", scene="cornell_box", preset="quick", config=long_render)
            assert other.get(f"/v1/jobs/{job['id']}").json()["id"] == job["id"]
            wait_for(other, job["id"], {"RUNNING"}, timeout=300)
            assert other.post(f"/v1/jobs/{job['id']}:cancel").status_code in (200, 202)
            followed = events(other, job["id"], timeout=300)
            assert followed[-1]["data"]["state"] == "CANCELLED"
            assert one.get(f"/v1/jobs/{job['id']}").json()["state"] == "CANCELLED"

            quick = {"samplers": 0, "spp": 4, "width": 16, "height": 16}
            ids = [
                submit(client, kind="render", scene="cornell_box", preset="quick", config=quick, seed=i)["id"]
                for i, client in enumerate([one, other, other])
            ]
            owners = {f"{socket.gethostname()}:{r.data_dir.resolve()}" for r in (api, second)}
            for job_id in ids:
                job_events = events(other, job_id, timeout=600)
                assert job_events[-1]["data"]["state"] == "SUCCEEDED", job_events[-1]
                started = [e["data"] for e in job_events if e["type"] == "log" and "scheduler" in e["data"]]
                assert len(started) == 1, started  # claimed once: no second scheduler ran it
                assert started[0]["scheduler"] in owners
    finally:
        second.stop(grace_s=TEARDOWN_GRACE_S)
