"""A scene's files as they live in the artifact store, fetched by digest into a cache on each node.

A job on another node cannot read the folder the API server unpacked an upload into: what travels with
the job is each file's store URL and sha256 digest, and every process that compiles the scene (the driver,
each sampler actor) downloads them once per node into `<cache>/<key>/`, verifying every byte against its
digest. The folder appears by an atomic rename, so processes racing on one node see either nothing or the
whole scene; the cache is keyed by content, so it never goes stale.

A stored artifact a scene's material names (`artifact: sha256:...`) travels the same way: the server adds
its files to the job's under `.artifacts/<hex>/` (`artifact_folder`), where the material loads it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import uuid
from pathlib import Path, PurePosixPath

from pydantic import BaseModel, ConfigDict, Field

from workers.scene.format.errors import SceneError

CACHE_ENV = "NBAKE_SCENE_CACHE"  # where a node keeps fetched scenes; default <temp dir>/nbake-scenes
CHUNK_BYTES = 1 << 20
ARTIFACTS_FOLDER = ".artifacts"  # in a job's scene folder: the stored artifacts its materials name


class StoredFile(BaseModel):
    model_config = ConfigDict(frozen=True)

    url: str  # fsspec URL of the blob (s3://bucket/prefix/blobs/sha256/ab/cd..., or a local path)
    digest: str = Field(pattern=r"^sha256:[0-9a-f]{64}$")


class StoredScene(BaseModel):
    """The files of an uploaded scene by their relative names, and the key (the asset id's hex) that
    names its cache folder."""

    model_config = ConfigDict(frozen=True)

    key: str = Field(pattern=r"^[0-9a-f]{64}$")
    files: dict[str, StoredFile]

    def local_folder(self, cache_dir: str | Path | None = None) -> Path:
        """The folder holding the scene's files on this node, fetched first if it is not cached."""
        cache = Path(cache_dir or os.environ.get(CACHE_ENV) or Path(tempfile.gettempdir()) / "nbake-scenes")
        folder = cache / self.key
        if folder.is_dir():
            return folder
        cache.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".fetch-{self.key[:12]}-", dir=cache))
        try:
            for name, stored in self.files.items():
                fetch(stored, staging / relative(name))
            try:
                staging.rename(folder)
            except OSError:  # another process on this node fetched it first: theirs is identical
                if not folder.is_dir():
                    raise
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return folder


def artifact_folder(artifact_id: str) -> PurePosixPath:
    """Where the files of the stored artifact `artifact_id` lie in the scene's folder of a job naming it."""
    return PurePosixPath(ARTIFACTS_FOLDER, artifact_id.removeprefix("sha256:"))


def relative(name: str) -> PurePosixPath:
    """`name` as a path inside the scene's folder; a name that could leave it is a SceneError."""
    path = PurePosixPath(name)
    if path.is_absolute() or not path.parts or any(part in ("", ".", "..") for part in path.parts):
        raise SceneError("files", f"{name!r} is not a relative path inside the scene's folder")
    return path


def fetch(stored: StoredFile, dest: Path) -> None:
    """Stream the blob at `stored.url` to `dest`, verified against its digest (a mismatch leaves no file)."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    temporary = dest.with_name(f".{dest.name}.{uuid.uuid4().hex}")
    hasher = hashlib.sha256()
    import fsspec  # here, not at import: every path tracer imports this module, few fetch

    try:
        with fsspec.open(stored.url, "rb") as source, open(temporary, "wb") as out:
            while chunk := source.read(CHUNK_BYTES):
                hasher.update(chunk)
                out.write(chunk)
        actual = f"sha256:{hasher.hexdigest()}"
        if actual != stored.digest:
            raise OSError(f"{stored.url} holds content {actual}, not the scene's {stored.digest}")
        temporary.replace(dest)
    finally:
        temporary.unlink(missing_ok=True)
