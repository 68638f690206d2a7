"""Artifacts: publish -> manifest -> file, stable content ids, tamper detection, checkpoints, GC."""

import hashlib
import json
from datetime import UTC, datetime, timedelta

import pytest

from services.artifacts.artifacts import ArtifactNotFound, ArtifactStore, FileNotFoundInArtifact
from services.artifacts.assets import Asset, save_asset
from services.artifacts.manifest import MEASUREMENT_FILES, MODEL_DIGEST, store_file
from services.artifacts.store import BlobCorrupted, BlobStore

CREATED = datetime(2025, 1, 2, 3, 4, 5, 678901, tzinfo=UTC)


@pytest.fixture
def store(tmp_path):
    return ArtifactStore(BlobStore(str(tmp_path / "store")), str(tmp_path / "store"))


@pytest.fixture
def outputs(tmp_path):
    folder = tmp_path / "output"
    folder.mkdir()
    (folder / "render.exr").write_bytes(b"EXR" * 100)
    (folder / "preview.png").write_bytes(b"PNG" * 50)
    (folder / "report.json").write_text('{"psnr": 40.0}')
    return folder


def publish(store, outputs, **overrides):
    fields = dict(
        kind="render",
        job_id="job-1",
        scene_hash="sha256:" + "1" * 64,
        config={"spp": 16, "size": [64, 64]},
        code_version="0.1.0+abc",
        metrics={"seconds": 1.5},
        created=CREATED,
    )
    files = {
        "render.exr": (str(outputs / "render.exr"), ""),
        "images/preview.png": (str(outputs / "preview.png"), "image/png"),
        "report.json": (str(outputs / "report.json"), "application/vnd.neuralbake.report+json"),
    }
    return store.publish(files, **(fields | overrides))


def test_publish_then_read_back_every_file(store, outputs):
    manifest = publish(store, outputs)
    again = store.manifest(manifest.artifact_id)
    assert again == manifest
    assert [entry.name for entry in again.files] == ["images/preview.png", "render.exr", "report.json"]
    entry = store.file(manifest.artifact_id, "render.exr")
    assert entry.media_type == "image/x-exr"  # inferred from the name
    assert entry.size == 300 and store.blobs.read(entry.digest) == b"EXR" * 100
    assert (
        store.file(manifest.artifact_id, "report.json").media_type == "application/vnd.neuralbake.report+json"
    )
    assert again.kind == "render" and again.config == {"spp": 16, "size": [64, 64]}
    assert again.created == CREATED


def test_the_artifact_id_is_the_sha256_of_the_canonical_manifest(store, outputs):
    manifest = publish(store, outputs)
    content = manifest.model_dump(mode="json", exclude={"artifact_id"})
    canonical = json.dumps(content, sort_keys=True, separators=(",", ":")).encode()
    assert manifest.artifact_id == "sha256:" + hashlib.sha256(canonical).hexdigest()
    assert store.blobs.read(manifest.artifact_id) == canonical  # the manifest is itself a blob


def test_artifact_ids_are_stable_for_equal_content_and_change_with_it(store, outputs):
    first = publish(store, outputs)
    assert publish(store, outputs).artifact_id == first.artifact_id
    assert publish(store, outputs, metrics={"seconds": 1.6}).artifact_id != first.artifact_id
    (outputs / "render.exr").write_bytes(b"other pixels")
    assert publish(store, outputs).artifact_id != first.artifact_id
    assert len(store.artifact_ids()) == 3


def test_the_model_digest_covers_every_file_but_the_reports_measurements(store, outputs):
    """Two runs of one job differ in their report's timings, their job, time and metrics, not their model."""
    first = publish(store, outputs).annotations[MODEL_DIGEST]
    (outputs / "report.json").write_text('{"psnr": 40.0, "seconds_per_frame": 0.2}')
    again = publish(store, outputs, job_id="job-2", metrics={"seconds": 1.6}, created=CREATED + timedelta(1))
    assert again.annotations[MODEL_DIGEST] == first
    (outputs / "render.exr").write_bytes(b"other pixels")
    assert publish(store, outputs).annotations[MODEL_DIGEST] != first
    from workers.runtime.report import MEDIA_TYPES  # the report's own files are the measurements

    assert set(MEDIA_TYPES) == MEASUREMENT_FILES


def test_a_tampered_manifest_is_detected(store, outputs):
    manifest = publish(store, outputs)
    path = store.blobs.local_path(manifest.artifact_id)
    path.write_bytes(path.read_bytes().replace(b'"render"', b'"evil!"'))
    with pytest.raises(BlobCorrupted):
        store.manifest(manifest.artifact_id)


def test_unknown_artifacts_and_files_are_lookup_errors(store, outputs):
    manifest = publish(store, outputs)
    with pytest.raises(ArtifactNotFound):
        store.manifest("sha256:" + "0" * 64)
    # a blob that is not a manifest is not an artifact
    file_digest = manifest.files[0].digest
    with pytest.raises(ArtifactNotFound):
        store.manifest(file_digest)
    with pytest.raises(FileNotFoundInArtifact, match=r"render\.exr"):
        store.file(manifest.artifact_id, "weights.safetensors")
    with pytest.raises(ValueError, match="not a digest"):
        store.manifest("../../etc/passwd")


@pytest.mark.parametrize("name", ["../escape.exr", "/abs.exr", "a\\b.exr", "./render.exr", ""])
def test_unsafe_or_unnormalised_file_names_are_refused(store, outputs, name):
    with pytest.raises(ValueError):
        store.publish(
            {name: (str(outputs / "render.exr"), "")},
            kind="render",
            job_id="job-1",
            scene_hash="x",
            config={},
            code_version="0",
            metrics={},
        )


def test_nan_metrics_are_refused(store, outputs):
    with pytest.raises(ValueError):
        publish(store, outputs, metrics={"psnr": float("nan")})


def test_checkpoints_live_per_job_outside_the_blob_store_until_collected(store, tmp_path):
    folder = store.checkpoint_dir("job-7")
    assert folder == str(tmp_path / "store" / "checkpoints" / "job-7")
    (tmp_path / "store" / "checkpoints" / "job-7" / "step_100.safetensors").write_bytes(b"w")
    assert store.checkpoint_dir("job-7") == folder  # existing checkpoints are kept for resuming
    assert (tmp_path / "store" / "checkpoints" / "job-7" / "step_100.safetensors").exists()
    store.checkpoint_dir("job-8")
    store.delete_checkpoints("job-7")
    assert not (tmp_path / "store" / "checkpoints" / "job-7").exists()
    assert (tmp_path / "store" / "checkpoints" / "job-8").is_dir()
    store.delete_checkpoints("job-7")  # collecting twice is fine


@pytest.mark.parametrize("job_id", ["../job", "a/b", "", ".", "..", "job\n"])
def test_job_ids_cannot_escape_the_checkpoint_root(store, job_id):
    with pytest.raises(ValueError, match="not a job id"):
        store.checkpoint_dir(job_id)
    with pytest.raises(ValueError, match="not a job id"):
        store.delete_checkpoints(job_id)


def test_gc_deletes_only_unreferenced_old_blobs(store, outputs, tmp_path):
    manifest = publish(store, outputs)
    mesh = tmp_path / "mesh.obj"
    mesh.write_bytes(b"v 0 0 0\n")
    scene = tmp_path / "scene.yaml"
    scene.write_bytes(b"name: kept\n")
    asset = Asset.from_files(
        "scene.yaml",
        "kept",
        [store_file(store.blobs, "scene.yaml", scene), store_file(store.blobs, "m.obj", mesh)],
    )
    save_asset(asset, store.blobs, store.root_url)
    orphan = store.blobs.put_bytes(b"orphan")
    pinned = store.blobs.put_bytes(b"pinned by the caller")

    assert store.gc_blobs(keep=set()) == []  # everything is younger than the grace period
    assert store.gc_blobs(keep={pinned}, grace=timedelta(0)) == [orphan]
    assert not store.blobs.exists(orphan) and store.blobs.exists(pinned)
    assert store.manifest(manifest.artifact_id) == manifest
    for entry in manifest.files + asset.files:
        store.blobs.verify(entry.digest)
