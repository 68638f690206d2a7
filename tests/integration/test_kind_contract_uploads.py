"""The kind contract on a user's own files: every registered kind trains its example on an uploaded folder
(`scene.yaml`, the modelled object as an OBJ with its MTL, another as a glTF with external buffers)
through `nbake serve`, with its driver and samplers on a Ray node that cannot see the server's data
folder: they read only the stored scene, fetched from the store by digest. A new kind gets this by
registering.

The server joins a one-node Ray cluster whose node runs in a mount namespace of its own, with a private
tmpfs over the server's data folder (`tests/support/cluster.py`), so no driver, sampler or actor of any
kind can read the server's files. The store is a folder both see, as a bucket would be.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.integration.test_api_server import TOKENS, TOKENS_ENV, events, submit
from tests.support.cluster import LocalCluster, ServeReplica
from tests.support.user_assets import user_folder
from workers.models.registry import get_kind, kind_names
from workers.runtime.contract import merge_nested
from workers.scene.generators.builtin import get_builtin

REPO = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.timeout(1200)
# The data path, not the model's quality, is what this checks (test_kind_contract.py gates quality on the
# built-in scenes): training kinds stop after a few steps and measure against a short reference.
SHORT = {"train": {"steps": 8}, "evaluation_spp": 2, "reference_spp": 8}


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[ServeReplica, LocalCluster]]:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("the worker node's own mount namespace needs root and unshare (CI runs as root)")
    root = Path(tempfile.mkdtemp(prefix="nbu-", dir="/tmp"))  # short: Ray's socket paths live below it
    (root / "server").mkdir()
    env = {"PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"}
    cluster = LocalCluster(root / "nodes", env)
    replica = None
    try:
        node = cluster.start_head(cpus=2, hidden=(root / "server",))
        replica = ServeReplica(
            root / "server" / "data",
            {
                **cluster.client_env,
                "NBAKE_STORE_URL": str(root / "store"),
                "NBAKE_TOKENS": TOKENS_ENV,
                "NBAKE_MAX_RUNNING": "2",
            },
        ).start()
        assert not node.sees(replica.data_dir), "the Ray node sees the server's data folder"
        yield replica, cluster
    finally:
        if replica is not None:
            replica.stop(grace_s=5)
        cluster.stop()
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(scope="module")
def client(server) -> Iterator[httpx.Client]:
    replica, _ = server
    headers = {"Authorization": f"Bearer {TOKENS['submit']}"}
    with httpx.Client(base_url=replica.url, headers=headers, timeout=60) as http:
        yield http


def overrides(name: str) -> dict:
    kind = get_kind(name)
    return merge_nested(kind.example.overrides, SHORT if kind.method is not None else {})


@pytest.fixture(scope="module")
def submitted(client) -> dict[str, dict]:
    """Every kind's job, all submitted at once (the server runs two at a time; their start-up and I/O
    overlap): kind name -> the job as submitted."""
    jobs = {}
    for name in kind_names():
        files = user_folder(get_builtin(get_kind(name).example.scene), f"user_{name}")
        response = client.post("/v1/assets", files=[("files", (n, data)) for n, data in files.items()])
        assert response.status_code == 201, response.text
        asset_id = response.json()["asset_id"]
        jobs[name] = submit(client, kind=name, scene=asset_id, preset="quick", config=overrides(name))
    return jobs


@pytest.mark.parametrize("name", kind_names())
def test_every_kind_trains_on_an_uploaded_folder_read_only_from_the_store(name, client, server, submitted):
    job_id = submitted[name]["id"]
    final = events(client, job_id, timeout=900)[-1]["data"]
    assert final["state"] == "SUCCEEDED", client.get(f"/v1/jobs/{job_id}").json()

    artifact_id = client.get(f"/v1/jobs/{job_id}").json()["artifact_id"]
    manifest = client.get(f"/v1/artifacts/{artifact_id}").json()
    assert manifest["files"] and all(math.isfinite(v) for v in manifest["metrics"].values())
    # the node fetched the scene into its own cache: the files it trained on came from the store
    (node,) = server[1].nodes
    cached = {p.name for p in node.scene_cache.rglob("*") if p.is_file()}
    assert {"mesh.obj", "model.gltf"} <= cached, cached
