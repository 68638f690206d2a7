"""The whole Ray cluster killed mid-job: `nbake serve` joined to an external cluster (`ray start` in process
trees of its own, as a deployment's head pod) outlives the SIGKILL of every process of that cluster. The
API keeps answering and reports Ray not ready, the running job goes back to the queue as an
infrastructure failure, the server connects again once the cluster is restarted on the same address, and
the job resumes from its checkpoint in the store to the image an uninterrupted render gives. The same
holds for the server's embedded cluster (no `RAY_ADDRESS`), which the server starts again by itself; and a
server that stops with its parent leaves an external cluster running.

Without Ray's GCS fault tolerance a restarted head is a new cluster: the server's connection to the old
one cannot be reused, so this is the server re-initialising Ray, not Ray recovering.
"""

from __future__ import annotations

import contextlib
import functools
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.test_api_server import NBAKE, TOKENS, TOKENS_ENV, events, submit, wait_for
from tests.integration.test_jobs_recovery import assert_uninterrupted_render
from tests.integration.test_serve_lifetime import PARENT, alive
from tests.support.cluster import LocalCluster, RayNode, ServeReplica
from tests.support.ports import free_port
from tests.support.sockets import process_tree
from workers.runtime.checkpoints import COMMIT_MARKER

REPO = Path(__file__).resolve().parents[2]
# Ray clusters started twice, servers and renders resumed: about five minutes on the shared 2-core machine
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]
SEED = 5
CONFIG = {"spp": 384, "checkpoint_interval_s": 0}
CPUS = 2
LOST = "the Ray cluster was lost"


@pytest.fixture
def cluster() -> Iterator[LocalCluster]:
    """A head node of its own (started again by the test after it killed it); every node is stopped by
    the PIDs of its session after the test, whatever happened."""
    root = Path(tempfile.mkdtemp(prefix="nbk-", dir="/tmp"))  # short: Ray's socket paths live below it
    cluster = LocalCluster(root / "nodes", {"PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"})
    try:
        cluster.start_head(cpus=CPUS)
        yield cluster
    finally:
        cluster.stop()
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def server(cluster) -> Iterator[ServeReplica]:
    env = {**cluster.client_env, "NBAKE_TOKENS": TOKENS_ENV, "NBAKE_MAX_RUNNING": "1"}
    folder = cluster.folder.parent / "server"
    folder.mkdir()
    replica = ServeReplica(folder / "data", env)
    try:
        yield replica.start()
    finally:
        replica.stop()


def readiness(client: httpx.Client) -> tuple[int, dict]:
    response = client.get("/readyz")
    return response.status_code, response.json()


def wait_until(condition, what: str, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"not within {timeout} s: {what}"
        time.sleep(0.25)


def interrupt_and_resume(
    server: ServeReplica, kill: Callable[[], None], restart: Callable[[httpx.Client, str], None]
) -> None:
    """A render killed with its whole Ray cluster after its first checkpoint and brought back by
    `restart(client, job_id)`: the API answers throughout, the job goes back to the queue and resumes to
    the uninterrupted image."""
    with httpx.Client(
        base_url=server.url, headers={"Authorization": f"Bearer {TOKENS['admin']}"}, timeout=30
    ) as client:
        job = submit(client, kind="render", scene="cornell_box", preset="quick", config=CONFIG, seed=SEED)
        checkpoints = server.data_dir / "store" / "checkpoints" / job["id"]
        wait_until(
            lambda: any(checkpoints.glob(f"step-*/{COMMIT_MARKER}")),
            "the render committed its first checkpoint",
            timeout=300,
        )

        kill()

        wait_until(lambda: readiness(client)[0] == 503, "/readyz reported Ray not ready")
        body = readiness(client)[1]
        assert body["checks"]["database"] == body["checks"]["store"] == "ok", body
        assert body["checks"]["ray"] != "ok", body
        queued = wait_for(client, job["id"], {"QUEUED", "FAILED"}, timeout=60)
        assert queued["state"] == "QUEUED", queued  # retried, not failed: the cluster's fault, not the job's
        assert client.get("/v1/jobs").status_code == 200  # the API answers while Ray is down

        restart(client, job["id"])

        done = wait_for(client, job["id"], {"SUCCEEDED", "FAILED"}, timeout=400)
        assert done["state"] == "SUCCEEDED", done
        assert readiness(client)[0] == 200
        stream = events(client, job["id"])
        image = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr").content

    assert [e["seq"] for e in stream] == list(range(1, len(stream) + 1))
    messages = [e["data"].get("message") or "" for e in stream]
    lost = next(i for i, message in enumerate(messages) if LOST in message)
    assert "retrying (attempt 2 of" in messages[lost], messages[lost]
    resumed = [m for m in messages[lost:] if "resuming from the checkpoint" in m]
    assert resumed, messages
    assert done["attempts"] == 2
    assert_uninterrupted_render(image, done["config"], SEED)


def test_a_killed_ray_cluster_is_reconnected_and_the_job_resumes_from_its_checkpoint(cluster, server):
    def restart(client: httpx.Client, job_id: str) -> None:
        time.sleep(3)  # the server tries to connect meanwhile; nothing runs until the cluster is back
        assert readiness(client)[0] == 503
        assert client.get(f"/v1/jobs/{job_id}").json()["state"] == "QUEUED"
        cluster.start_head(cpus=CPUS, name="head-restarted")  # the same address, a new cluster

    interrupt_and_resume(server, kill=cluster.stop, restart=restart)  # stop: SIGKILL to every process


def test_a_killed_embedded_cluster_is_started_again_and_the_job_resumes():
    """Without `RAY_ADDRESS` the cluster is the server's own child processes: killed, the server starts a
    new one by itself."""
    root = Path(tempfile.mkdtemp(prefix="nbe-", dir="/tmp"))  # short: the embedded cluster's sockets
    replica = ServeReplica(root / "data", {"NBAKE_TOKENS": TOKENS_ENV, "NBAKE_MAX_RUNNING": "1"})
    try:
        replica.start()
        kill = functools.partial(kill_ray_below, replica.process.pid)
        interrupt_and_resume(replica, kill=kill, restart=lambda *_: None)  # the server restarts it
    finally:
        replica.stop()
        shutil.rmtree(root, ignore_errors=True)


def kill_ray_below(server: int) -> None:
    """SIGKILL every Ray process below `server` (its embedded cluster), until none is left; the server
    itself and anything else it started live on."""
    deadline = time.monotonic() + 30
    while ray_processes := [pid for pid in process_tree(server) - {server} if is_ray(pid)]:
        assert time.monotonic() < deadline, f"Ray processes survived SIGKILL: {ray_processes}"
        for pid in ray_processes:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(0.1)


def is_ray(pid: int) -> bool:
    """A live (not zombie) process of a Ray cluster: its binaries, or Python running Ray's own code."""
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
        command = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    found = comm in ("gcs_server", "raylet") or comm.startswith("ray::") or b"/site-packages/ray/" in command
    return found and alive(pid)


def test_a_server_whose_parent_died_stops_without_stopping_the_external_cluster(cluster, tmp_path):
    """A server joined to a cluster it did not start ends with its parent, and leaves the cluster running."""
    port, log = free_port(), tmp_path / "server.log"
    command = [NBAKE, "serve", "--port", str(port), "--grpc-port", str(free_port())]
    command += ["--data-dir", str(tmp_path / "data"), "--log-level", "warning"]
    env = {**os.environ, **cluster.client_env, "NBAKE_TOKENS": TOKENS_ENV}
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(log), *command], stdout=subprocess.PIPE, text=True, env=env
    )
    server = int(parent.stdout.readline())
    try:
        wait_until(lambda: ready(f"http://127.0.0.1:{port}"), "the server got ready")
        head = cluster.nodes[0]
        cluster_processes = [head.raylet_pid(), gcs_server_pid(head)]
        parent.kill()
        parent.wait()
        wait_until(lambda: not alive(server), "the server stopped with its parent", timeout=90)
        assert f"the parent process {parent.pid} exited" in log.read_text()
        assert all(alive(pid) for pid in cluster_processes), "the server took the external cluster down"
        assert len(cluster.alive_nodes()) == 1
    finally:
        if alive(server):
            os.kill(server, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()
            parent.wait()


def gcs_server_pid(node: RayNode) -> int:
    return next(pid for pid in node.pids() if Path(f"/proc/{pid}/comm").read_text().strip() == "gcs_server")


def ready(url: str) -> bool:
    try:
        return httpx.get(f"{url}/readyz", timeout=5).status_code == 200
    except httpx.HTTPError:
        return False
