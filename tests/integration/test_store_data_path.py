"""Nothing a job reads or writes is on a shared filesystem: the scene, checkpoints and outputs go through
the artifact store, on `file://` (the embedded default) and on `s3://` (moto's S3 server; everything else
is real). A render of an uploaded mesh runs through the driver's `run_job` with only store URLs, is
cancelled past its first checkpoint, resumes from the store, and ends bit-identical to an uninterrupted
run; the scene reaches a fresh node cache by digest, verified.
"""

from __future__ import annotations

import io
import threading
from collections.abc import Iterator

import fsspec
import numpy as np
import pytest

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.assets import save_asset
from services.artifacts.staging import UploadLimits
from services.artifacts.store import BlobStore
from services.artifacts.uploads import ingest_upload
from services.jobs.scenes import SceneResolver
from tests.integration.test_lod_uploaded_asset import blob_obj, scene_yaml
from tests.support.s3 import S3Server, moto_s3
from workers.driver.jobs import JobEvent, JobSpec, run_job
from workers.models.registry import get_kind
from workers.runtime.checkpoints import COMMIT_MARKER, CheckpointStore
from workers.scene.importers.image_io import read_exr
from workers.scene.portability.io import load_scene
from workers.scene.portability.stored import StoredScene


def in_store(url: str, store_url: str) -> bool:
    """`url` names a file inside the store at `store_url` (same file system, below its root)."""
    (fs, path), (store_fs, root) = fsspec.core.url_to_fs(url), fsspec.core.url_to_fs(store_url)
    return type(fs) is type(store_fs) and path.startswith(root.rstrip("/") + "/")


@pytest.fixture(scope="module")
def s3() -> Iterator[S3Server]:
    with moto_s3() as server:
        yield server


@pytest.fixture(params=["file", "s3"])
def store_url(request, tmp_path) -> str:
    if request.param == "file":
        return str(tmp_path / "store")
    server = request.getfixturevalue("s3")
    return f"s3://{server.bucket()}/nbake"


@pytest.fixture
def uploaded(store_url, tmp_path) -> tuple[SceneResolver, dict]:
    """The blob-mesh scene uploaded into the store as an asset; (resolver, its scene reference)."""
    blobs = BlobStore(store_url)
    files = [("scene.yaml", scene_yaml()), ("meshes/blob.obj", blob_obj())]
    asset = ingest_upload([(name, io.BytesIO(data)) for name, data in files], blobs, UploadLimits())
    save_asset(asset, blobs, store_url)
    resolver = SceneResolver(blobs, store_url, tmp_path / "api-scenes")
    return resolver, resolver.resolve(asset.asset_id).ref


def test_checkpoints_commit_resume_and_vanish_through_the_store(store_url):
    store = CheckpointStore(f"{store_url}/checkpoints/job-1", keep=2)
    for step in (1, 2, 3):
        store.save(step, {"model.safetensors": bytes([step]) * 1000, "loop.json": b"{}"})
    crashed = f"{store.root}/step-000000009"  # a writer that died before its commit marker
    store.fs.makedirs(crashed, exist_ok=True)
    store.fs.pipe_file(f"{crashed}/model.safetensors", b"half")
    elsewhere = CheckpointStore(f"{store_url}/checkpoints/job-1", keep=2)  # another node's view
    assert elsewhere.steps() == [2, 3]
    assert elsewhere.load(3) == {"model.safetensors": bytes([3]) * 1000, "loop.json": b"{}"}
    elsewhere.save(4, {"model.safetensors": b"four"})
    assert store.steps() == [3, 4]
    assert not store.fs.exists(f"{crashed}/model.safetensors")
    with pytest.raises(ValueError, match="commit marker"):
        store.save(5, {COMMIT_MARKER: b"[]"})
    store.delete()
    assert CheckpointStore(f"{store_url}/checkpoints/job-1").steps() == []


def test_a_node_fetches_the_scene_by_digest_into_its_own_cache(uploaded, tmp_path):
    resolver, ref = uploaded
    stored = resolver.stored_files(ref, resolver.resolve(ref["asset_id"]).spec_json)
    assert all(in_store(f.url, resolver.blobs.url) for f in stored.files.values())
    folder = stored.local_folder(tmp_path / "node-cache")
    assert (folder / "meshes" / "blob.obj").read_bytes() == blob_obj()
    spec, _ = load_scene(folder / "scene.yaml")
    assert spec.name == "scanned_blob"
    assert stored.local_folder(tmp_path / "node-cache") == folder  # cached: fetched once per node

    entry = stored.files["meshes/blob.obj"]
    fs, path = fsspec.core.url_to_fs(entry.url)
    fs.pipe_file(path, b"v 0 0 0\n")  # the store was damaged
    with pytest.raises(OSError, match=entry.digest):
        stored.local_folder(tmp_path / "other-node-cache")
    assert not (tmp_path / "other-node-cache" / stored.key).exists()


def test_stored_file_names_cannot_leave_the_scene_folder(tmp_path):
    digest = "sha256:" + "0" * 64
    for name in ("../escape.obj", "/etc/passwd", "a/../../b"):
        stored = StoredScene(key="1" * 64, files={name: {"url": str(tmp_path / "x"), "digest": digest}})
        with pytest.raises(ValueError, match="relative path"):
            stored.local_folder(tmp_path / "cache")


def render_spec(resolver: SceneResolver, ref: dict, artifacts: ArtifactStore, job_id: str) -> JobSpec:
    """What the scheduler hands a driver: store URLs only (no local folder of the server's)."""
    config = get_kind("render").resolve_config(
        "quick", {"samplers": 0, "width": 32, "height": 32, "spp": 128, "tile_size": 32}
    )
    scene = resolver.resolve(ref["asset_id"]).spec_json
    return JobSpec(
        job_id=job_id,
        kind="render",
        scene=scene,
        scene_files=resolver.stored_files(ref, scene),
        config=config.model_dump(mode="json"),
        seed=3,
        checkpoint_dir=artifacts.checkpoint_dir(job_id),
        output_url=artifacts.output_url(job_id),
    )


def run(spec: JobSpec, cancel_at_progress: int | None = None):
    events: list[JobEvent] = []
    cancel = threading.Event()

    def sink(event: JobEvent) -> None:
        events.append(event)
        if event.type == "progress" and cancel_at_progress is not None and event.step >= cancel_at_progress:
            cancel.set()

    return run_job(spec, sink, cancel), events


def test_a_render_reads_and_writes_only_through_the_store_and_resumes_from_it(
    uploaded, store_url, tmp_path, monkeypatch
):
    monkeypatch.setenv("NBAKE_SCENE_CACHE", str(tmp_path / "driver-cache"))
    resolver, ref = uploaded
    artifacts = ArtifactStore(resolver.blobs, store_url)

    whole, _ = run(render_spec(resolver, ref, artifacts, "whole"))
    assert whole.state == "succeeded", whole.error
    spec = render_spec(resolver, ref, artifacts, "interrupted")
    stopped, _ = run(spec, cancel_at_progress=1)
    assert stopped.state == "cancelled"
    assert CheckpointStore(spec.checkpoint_dir).latest() is not None  # its resume point is in the store
    resumed, events = run(spec)
    assert resumed.state == "succeeded", resumed.error
    assert any("resuming from the checkpoint" in (e.message or "") for e in events)

    assert set(resumed.files) == set(whole.files)
    for name, url in resumed.files.items():
        assert in_store(url, store_url) and url.endswith(f"outputs/{spec.job_id}/{name}")
    images = [
        read_exr(artifacts.local_output(outcome.files["image.exr"], tmp_path / job / "image.exr"))
        for outcome, job in ((whole, "whole"), (resumed, "interrupted"))
    ]
    np.testing.assert_array_equal(images[0], images[1])
    assert np.mean(images[0]) > 0.01  # the lit blob, not a black frame

    manifest = artifacts.publish(
        {n: (str(artifacts.local_output(u, tmp_path / "pub" / n)), "") for n, u in resumed.files.items()},
        kind="render",
        job_id=spec.job_id,
        scene_hash="sha256:" + "2" * 64,
        config=spec.config,
        code_version="test",
        metrics=resumed.metrics,
    )
    assert artifacts.manifest(manifest.artifact_id).file("image.exr") is not None
    artifacts.delete_checkpoints(spec.job_id)
    artifacts.delete_outputs(spec.job_id)
    assert CheckpointStore(spec.checkpoint_dir).latest() is None
    assert not artifacts.fs.exists(f"{artifacts.root}/outputs/{spec.job_id}")
