"""Artifacts: files published from a finished job, addressed by their manifest's id.

The manifest is stored as a blob (its digest is the artifact id, so reading it re-verifies
it) and indexed under `<root>/manifests/<hex>.json`. Checkpoints are mutable, so they live
outside the content-addressed store, under `<checkpoint root>/<job_id>/`, until the job ends.
"""

from __future__ import annotations

import json
import re
import shutil
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import fsspec
from fsspec.implementations.local import LocalFileSystem

from services.artifacts.assets import asset_ids, load_asset
from services.artifacts.digests import parse_digest
from services.artifacts.manifest import FileEntry, Manifest, store_file
from services.artifacts.paths import safe_relative_path
from services.artifacts.store import BlobNotFound, BlobStore, indexed_digests, write_atomic

_JOB_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


class ArtifactNotFound(LookupError):
    def __init__(self, artifact_id: str):
        self.artifact_id = artifact_id
        super().__init__(f"artifact not found: {artifact_id}")


class FileNotFoundInArtifact(LookupError):
    def __init__(self, artifact_id: str, name: str, known: list[str]):
        self.artifact_id = artifact_id
        self.name = name
        super().__init__(f"artifact {artifact_id} has no file {name!r} (it has: {', '.join(known)})")


class ArtifactStore:
    """Manifests and checkpoints under `root_url`; file contents in `blobs`.

    `checkpoint_root` defaults to `<root>/checkpoints` and must be local (workers write there).
    """

    def __init__(self, blobs: BlobStore, root_url: str, checkpoint_root: str | Path | None = None):
        self.blobs = blobs
        self.root_url = str(root_url)
        self.fs, root = fsspec.core.url_to_fs(self.root_url)
        self.root = root.rstrip("/")
        if checkpoint_root is None:
            if not isinstance(self.fs, LocalFileSystem):
                raise ValueError("checkpoints need a local folder: pass checkpoint_root for a remote store")
            checkpoint_root = Path(self.root) / "checkpoints"
        self.checkpoint_root = Path(checkpoint_root)

    # ------------------------------------------------------------------ artifacts

    def publish(
        self,
        files: dict[str, tuple[str, str]],
        *,
        kind: str,
        job_id: str,
        scene_hash: str,
        config: dict[str, Any],
        code_version: str,
        metrics: dict[str, float],
        annotations: dict[str, str] | None = None,
        created: datetime | None = None,
    ) -> Manifest:
        """Store `files` (name -> (local path, media type or "" to infer)) and their manifest."""
        entries = []
        for name, (path, media_type) in sorted(files.items()):
            clean = safe_relative_path(name)
            if clean != name:
                raise ValueError(f"artifact file name {name!r} is not normalised: use {clean!r}")
            entries.append(store_file(self.blobs, name, path, media_type))
        manifest = Manifest.build(
            kind=kind,
            job_id=job_id,
            scene_hash=scene_hash,
            config=config,
            code_version=code_version,
            metrics=metrics,
            created=created or datetime.now(UTC),
            files=entries,
            annotations=annotations or {},
        )
        stored = self.blobs.put_bytes(manifest.canonical_bytes())
        assert stored == manifest.artifact_id, "the artifact id is the digest of the canonical manifest"
        index = manifest.model_dump_json(indent=2).encode()
        write_atomic(self.fs, self._index(manifest.artifact_id), [index])
        return manifest

    def manifest(self, artifact_id: str) -> Manifest:
        """The manifest, read from its blob and so verified against `artifact_id`."""
        if not self.fs.exists(self._index(artifact_id)):
            raise ArtifactNotFound(artifact_id)
        try:
            content = json.loads(self.blobs.read(artifact_id))
        except BlobNotFound:
            raise ArtifactNotFound(artifact_id) from None
        return Manifest.model_validate({**content, "artifact_id": artifact_id})

    def file(self, artifact_id: str, name: str) -> FileEntry:
        manifest = self.manifest(artifact_id)
        entry = manifest.file(name)
        if entry is None:
            raise FileNotFoundInArtifact(artifact_id, name, [e.name for e in manifest.files])
        return entry

    def artifact_ids(self) -> list[str]:
        return indexed_digests(self.fs, f"{self.root}/manifests")

    def _index(self, artifact_id: str) -> str:
        return f"{self.root}/manifests/{parse_digest(artifact_id)}.json"

    # ------------------------------------------------------------------ checkpoints

    def checkpoint_dir(self, job_id: str) -> str:
        """The (created) local folder for `job_id`'s checkpoints."""
        path = self._checkpoint_path(job_id)
        path.mkdir(parents=True, exist_ok=True)
        return str(path)

    def delete_checkpoints(self, job_id: str) -> None:
        """Garbage collection for a finished job; nothing to delete is fine."""
        path = self._checkpoint_path(job_id)
        if path.exists():
            shutil.rmtree(path)

    def _checkpoint_path(self, job_id: str) -> Path:
        if not isinstance(job_id, str) or _JOB_ID.fullmatch(job_id) is None:
            raise ValueError(f"not a job id: {job_id!r}")
        return self.checkpoint_root / job_id

    # ------------------------------------------------------------------ garbage collection

    def gc_blobs(self, keep: set[str], grace: timedelta = timedelta(hours=1)) -> list[str]:
        """Delete blobs referenced by no manifest, no saved asset and not in `keep`; the deleted digests.

        Blobs younger than `grace` survive: a publish or upload in progress has stored its
        files but not yet the manifest or listing that references them.
        """
        referenced = set(keep)
        for artifact_id in self.artifact_ids():
            referenced.add(artifact_id)
            referenced.update(entry.digest for entry in self.manifest(artifact_id).files)
        for asset_id in asset_ids(self.root_url):
            referenced.update(entry.digest for entry in load_asset(asset_id, self.root_url).files)
        cutoff = datetime.now(UTC) - grace
        deleted = []
        for digest in list(self.blobs.digests()):
            if digest not in referenced and self.blobs.modified(digest) <= cutoff:
                self.blobs.delete(digest)
                deleted.append(digest)
        return deleted
