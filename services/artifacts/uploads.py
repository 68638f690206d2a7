"""Turning a multipart upload (loose scene files, or one zip/tar archive) into a validated Asset.

Everything is staged and checked on local disk first; blobs are written only for an upload
whose scene parses, references only files of the upload, and compiles.
"""

from __future__ import annotations

import tempfile
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, BinaryIO

from services.artifacts.archives import extract_archive, is_archive
from services.artifacts.assets import Asset, AssetNotFound, load_asset, materialize, save_asset
from services.artifacts.manifest import store_file
from services.artifacts.staging import PAYLOAD_TOO_LARGE, Staging, UploadError, UploadLimits
from services.artifacts.store import BlobStore, read_chunks
from services.artifacts.validation import validate_scene
from workers.scene.portability.io import IMPORTED_SCENE_SUFFIXES, SCENE_FILE_SUFFIXES

if TYPE_CHECKING:
    from services.geometry import GeometryProcesses

__all__ = [
    "Asset",
    "AssetNotFound",
    "UploadError",
    "UploadLimits",
    "find_scene_file",
    "ingest_upload",
    "load_asset",
    "materialize",
    "save_asset",
]

_ROOT_SCENE_NAMES = {f"scene{suffix}" for suffix in SCENE_FILE_SUFFIXES}


def ingest_upload(
    parts: list[tuple[str, BinaryIO]],
    blobs: BlobStore,
    limits: UploadLimits,
    work_dir: Path | None = None,
    geometry: GeometryProcesses | None = None,
) -> Asset:
    """Stage, check and store `parts` ((file name, stream) pairs); UploadError or SceneError if unusable.
    The scene's geometry is built in `geometry`'s child processes when given.

    The Asset is not saved: call `save_asset` to make it findable by id.
    """
    if not parts:
        raise UploadError("files", "the upload is empty: send a scene file and its meshes, or one archive")
    with tempfile.TemporaryDirectory(prefix="nbake-upload-", dir=work_dir) as temporary:
        staging = Staging(Path(temporary) / "files", limits)
        staging.root.mkdir()
        archives = [name for name, _ in parts if is_archive(name)]
        if archives and len(parts) > 1:
            raise UploadError(archives[0], "send one archive on its own, or loose files without an archive")
        if archives:
            name, stream = parts[0]
            extract_archive(_spool(name, stream, Path(temporary) / "archive", limits), name, staging)
        else:
            for name, stream in parts:
                staging.add(name, read_chunks(stream))
        if not staging.files:
            raise UploadError("files", "the upload holds no files")
        scene_file = find_scene_file(list(staging.files))
        spec = validate_scene(staging.root, scene_file, set(staging.files), geometry)
        entries = [store_file(blobs, name, path) for name, path in sorted(staging.files.items())]
    return Asset.from_files(scene_file, spec.name, entries)


def find_scene_file(names: list[str]) -> str:
    """`scene.yaml|yml|json` at the root, else the only YAML/JSON file, else the only glTF file; UploadError
    if ambiguous or absent."""
    at_root = sorted(n for n in names if n.lower() in _ROOT_SCENE_NAMES)
    candidates = at_root or sorted(n for n in names if PurePosixPath(n).suffix.lower() in SCENE_FILE_SUFFIXES)
    candidates = candidates or sorted(
        n for n in names if PurePosixPath(n).suffix.lower() in IMPORTED_SCENE_SUFFIXES
    )
    if len(candidates) == 1:
        return candidates[0]
    if not candidates:
        raise UploadError(
            "files",
            "no scene file: add scene.yaml (or .yml, .json) at the root of the upload, or a .gltf/.glb",
        )
    raise UploadError(
        "files", f"several possible scene files ({', '.join(candidates)}): keep one, or name it scene.yaml"
    )


def _spool(name: str, stream: BinaryIO, dest: Path, limits: UploadLimits) -> Path:
    """Copy the archive to local disk (archives need seeking), refusing more than the total limit."""
    size = 0
    with open(dest, "wb") as out:
        for chunk in read_chunks(stream):
            size += len(chunk)
            if size > limits.max_total_bytes:
                problem = f"the archive exceeds the limit of {limits.max_total_bytes} bytes in total"
                raise UploadError(name, problem, PAYLOAD_TOO_LARGE)
            out.write(chunk)
    return dest
