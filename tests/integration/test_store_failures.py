"""The artifact store failing on write (a full disk, simulated by a filesystem whose writes fail with
ENOSPC): the job retries the publish, no partial artifact is ever visible, and every stored blob verifies
against its digest afterwards."""

from __future__ import annotations

from pathlib import Path

import pytest

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobStore
from tests.integration.test_api_server import (
    FINAL,
    QUICK_RENDER,
    DatabaseChoice,
    ServerThread,
    events,
    settings_for,
    submit,
    wait_for,
)
from tests.support.failing_fs import PROTOCOL, FailingFileSystem, register


@pytest.fixture
def full_disk():
    register()
    yield FailingFileSystem
    FailingFileSystem.failures_left, FailingFileSystem.failed = 0, 0


@pytest.mark.slow  # two attempts of a render job: ~17 s, over this branch's share of the default suite
def test_a_failing_store_write_is_retried_and_leaves_no_partial_artifact(ray_cluster, full_disk, tmp_path):
    store_url = f"{PROTOCOL}://{tmp_path / 'store'}"
    settings = settings_for(tmp_path / "data", DatabaseChoice("sqlite", None), store_url=store_url)
    with ServerThread(settings) as server, server.client("admin") as client:
        full_disk.failures_left = 1  # the first write of the first publish
        job = submit(client, **QUICK_RENDER)
        done = wait_for(client, job["id"], FINAL, timeout=300)
        assert done["state"] == "SUCCEEDED", done["error"]
        assert full_disk.failed == 1 and done["attempts"] == 2
        messages = [e["data"].get("message") or "" for e in events(client, job["id"]) if e["type"] == "state"]
        assert any("publishing the artifact failed" in m and "No space left" in m for m in messages)
        response = client.get(f"/v1/artifacts/{done['artifact_id']}/files/image.exr")
        assert response.status_code == 200
    blobs = BlobStore(store_url)
    artifacts = ArtifactStore(blobs, store_url)
    assert artifacts.artifact_ids() == [done["artifact_id"]]  # nothing half-published is listed
    leftovers = [p for p in Path(tmp_path / "store").rglob("*") if ".tmp-" in p.name]
    assert not leftovers, leftovers
    digests = list(blobs.digests())
    assert digests
    for digest in digests:
        blobs.verify(digest)
