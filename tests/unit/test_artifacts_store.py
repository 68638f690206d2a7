"""The content-addressed blob store: round trips, idempotence, atomicity, verification, digest checks."""

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from services.artifacts.media_types import media_type_for
from services.artifacts.store import BlobCorrupted, BlobNotFound, BlobStore


def sha(data: bytes) -> str:
    return "sha256:" + hashlib.sha256(data).hexdigest()


def stored_files(root: Path) -> list[Path]:
    return sorted(p for p in (root / "blobs").rglob("*") if p.is_file())


def flip_first_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[0] ^= 0xFF
    path.write_bytes(bytes(data))


def test_put_and_read_round_trip_with_the_documented_layout(tmp_path):
    blobs = BlobStore(str(tmp_path))
    data = b"weights" * 1000
    digest = blobs.put_bytes(data)
    hex_digest = hashlib.sha256(data).hexdigest()
    assert digest == sha(data)
    assert blobs.local_path(digest) == tmp_path / "blobs" / "sha256" / hex_digest[:2] / hex_digest[2:]
    assert blobs.read(digest) == data
    assert blobs.exists(digest) and blobs.size(digest) == len(data)
    with blobs.open(digest) as stream:
        assert stream.read() == data
    blobs.verify(digest)
    assert list(blobs.digests()) == [digest]


def test_put_file_streams_large_files_and_download_writes_them_back(tmp_path):
    source = tmp_path / "big.bin"
    source.write_bytes(os.urandom(3 * (1 << 20) + 17))  # more than one chunk, not a multiple of it
    blobs = BlobStore(str(tmp_path / "store"))
    digest = blobs.put_file(source)
    assert digest == sha(source.read_bytes())
    copy = blobs.download(digest, tmp_path / "out" / "copy.bin")
    assert copy.read_bytes() == source.read_bytes()


def test_file_urls_and_plain_paths_address_the_same_store(tmp_path):
    digest = BlobStore(f"file://{tmp_path}").put_bytes(b"shared")
    assert BlobStore(str(tmp_path)).read(digest) == b"shared"


def test_puts_are_idempotent_and_leave_no_temporary_files(tmp_path):
    blobs = BlobStore(str(tmp_path))
    source = tmp_path / "scene.yaml"
    source.write_bytes(b"name: x\n")
    digests = {blobs.put_bytes(b"name: x\n"), blobs.put_bytes(b"name: x\n"), blobs.put_file(source)}
    assert len(digests) == 1
    assert [p.name for p in stored_files(tmp_path)] == [digests.pop()[len("sha256:") + 2 :]]


def test_concurrent_puts_of_the_same_content_are_safe(tmp_path):
    blobs = BlobStore(str(tmp_path))
    data = os.urandom(1 << 20)
    source = tmp_path / "data.bin"
    source.write_bytes(data)

    def put(i: int) -> str:
        return blobs.put_bytes(data) if i % 2 else blobs.put_file(source)

    with ThreadPoolExecutor(max_workers=8) as pool:
        digests = set(pool.map(put, range(32)))
    assert digests == {sha(data)}
    assert blobs.read(sha(data)) == data
    assert len(stored_files(tmp_path)) == 1  # no temporary file survives


def test_a_flipped_byte_is_detected_by_every_verified_read(tmp_path):
    blobs = BlobStore(str(tmp_path))
    data = b"0123456789" * 100
    digest = blobs.put_bytes(data)
    flip_first_byte(blobs.local_path(digest))
    actual = sha(b"\xcf" + data[1:])
    with pytest.raises(BlobCorrupted) as caught:
        blobs.read(digest)
    assert caught.value.digest == digest and caught.value.actual == actual
    assert digest in str(caught.value) and actual in str(caught.value)
    with pytest.raises(BlobCorrupted):
        blobs.verify(digest)
    with pytest.raises(BlobCorrupted):
        blobs.download(digest, tmp_path / "out.bin")
    assert not (tmp_path / "out.bin").exists()


def test_putting_the_content_again_repairs_a_truncated_blob(tmp_path):
    blobs = BlobStore(str(tmp_path))
    digest = blobs.put_bytes(b"precious data")
    blobs.local_path(digest).write_bytes(b"prec")
    assert blobs.put_bytes(b"precious data") == digest
    assert blobs.read(digest) == b"precious data"


def test_missing_blobs_raise_blob_not_found(tmp_path):
    blobs = BlobStore(str(tmp_path))
    absent = sha(b"never stored")
    assert not blobs.exists(absent)
    for call in (blobs.read, blobs.open, blobs.size, blobs.verify, blobs.local_path):
        with pytest.raises(BlobNotFound):
            call(absent)
    blobs.delete(absent)  # deleting nothing is fine


def test_delete_removes_a_blob(tmp_path):
    blobs = BlobStore(str(tmp_path))
    digest = blobs.put_bytes(b"temporary")
    blobs.delete(digest)
    assert not blobs.exists(digest)
    with pytest.raises(BlobNotFound):
        blobs.read(digest)


@pytest.mark.parametrize(
    "bad",
    [
        "",
        "sha256:",
        "sha256:" + "a" * 63,
        "sha256:" + "a" * 65,
        "sha256:" + "A" * 64,
        "SHA256:" + "a" * 64,
        "md5:" + "a" * 32,
        "a" * 64,
        "sha256:" + "a" * 64 + "\n",
        "sha256:../../" + "a" * 58,
        "sha256:" + "g" * 64,
        None,
    ],
)
def test_malformed_digests_are_rejected_before_touching_the_store(tmp_path, bad):
    blobs = BlobStore(str(tmp_path))
    for call in (blobs.read, blobs.exists, blobs.delete, blobs.open, blobs.local_path):
        with pytest.raises(ValueError, match="not a digest"):
            call(bad)


@pytest.mark.parametrize(
    ("name", "media_type"),
    [
        ("render.exr", "image/x-exr"),
        ("images/Preview.PNG", "image/png"),
        ("report.json", "application/json"),
        ("weights.safetensors", "application/vnd.safetensors"),
        ("scene.yml", "application/yaml"),
        ("meshes/a.obj", "model/obj"),
        ("a.ply", "model/x-ply"),
        ("a.glb", "model/gltf-binary"),
        ("unknown.xyz", "application/octet-stream"),
        ("no_suffix", "application/octet-stream"),
    ],
)
def test_media_types_follow_the_suffix(name, media_type):
    assert media_type_for(name) == media_type
