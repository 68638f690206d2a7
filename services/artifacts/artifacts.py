"""Artifacts: files published from a finished job, addressed by their manifest's id.

The manifest is stored as a blob (its digest is the artifact id, so reading it re-verifies
it) and indexed under `<root>/manifests/<hex>.json`. Checkpoints and a job's outputs are mutable,
so they live outside the content-addressed store, under `<root>/checkpoints/<job_id>/` and
`<root>/outputs/<job_id>/`, until the job ends. Both are in the store itself (`s3://` at scale), so a
driver on any node writes them and a job resumes wherever it runs next.
"""

from __future__ import annotations

import json
import re
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import fsspec
from fsspec.implementations.local import LocalFileSystem

from services.artifacts.assets import asset_ids, load_asset
from services.artifacts.digests import parse_digest
from services.artifacts.manifest import MODEL_DIGEST, FileEntry, Manifest, model_digest, store_file
from services.artifacts.paths import safe_relative_path
from services.artifacts.store import BlobNotFound, BlobStore, indexed_digests, write_atomic

_JOB_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


def checked_job_id(job_id: str) -> str:
    """`job_id`, which becomes a folder name in the store: ValueError unless it is one plain name."""
    if not isinstance(job_id, str) or _JOB_ID.fullmatch(job_id) is None:
        raise ValueError(f"not a job id: {job_id!r}")
    return job_id


def _remove_tree(fs, path: str) -> None:
    """Remove `path` and everything below it; nothing there is fine (collection may run twice)."""
    fs.invalidate_cache(path)
    if fs.exists(path):
        fs.rm(path, recursive=True)


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
    """Manifests, checkpoints and job outputs under `root_url`; file contents in `blobs`.

    `checkpoint_root` (a local path or fsspec URL) defaults to `<root>/checkpoints`.
    """

    def __init__(self, blobs: BlobStore, root_url: str, checkpoint_root: str | Path | None = None):
        self.blobs = blobs
        self.root_url = str(root_url)
        self.fs, root = fsspec.core.url_to_fs(self.root_url)
        self.root = root.rstrip("/")
        self.checkpoint_fs, checkpoint_path = fsspec.core.url_to_fs(
            str(checkpoint_root) if checkpoint_root is not None else self._url("checkpoints")
        )
        self.checkpoint_root = checkpoint_path.rstrip("/")

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
        """Store `files` (name -> (local path, media type or "" to infer)) and their manifest, annotated
        with the model's digest (`manifest.model_digest`)."""
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
            annotations={MODEL_DIGEST: model_digest(entries), **(annotations or {})},
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
        """Where `job_id`'s checkpoints live (created): a local path, or a URL every node can reach."""
        path = f"{self.checkpoint_root}/{checked_job_id(job_id)}"
        self.checkpoint_fs.makedirs(path, exist_ok=True)
        return (
            path
            if isinstance(self.checkpoint_fs, LocalFileSystem)
            else self.checkpoint_fs.unstrip_protocol(path)
        )

    def delete_checkpoints(self, job_id: str) -> None:
        """Garbage collection for a finished job; nothing to delete is fine."""
        _remove_tree(self.checkpoint_fs, f"{self.checkpoint_root}/{checked_job_id(job_id)}")

    # ------------------------------------------------------------------ job outputs

    def output_url(self, job_id: str) -> str:
        """Where the driver of `job_id` uploads the artifact's files before the service publishes them."""
        return self._url(f"outputs/{checked_job_id(job_id)}")

    @staticmethod
    def local_output(url: str, download_to: Path) -> Path:
        """A local file with the content of the uploaded output at `url`: the file itself in a local
        store, else a download to `download_to`."""
        fs, path = fsspec.core.url_to_fs(url)
        if isinstance(fs, LocalFileSystem):
            return Path(path)
        download_to.parent.mkdir(parents=True, exist_ok=True)
        fs.get_file(path, str(download_to))
        return download_to

    def delete_outputs(self, job_id: str) -> None:
        _remove_tree(self.fs, f"{self.root}/outputs/{checked_job_id(job_id)}")

    def _url(self, relative: str) -> str:
        path = f"{self.root}/{relative}"
        return path if isinstance(self.fs, LocalFileSystem) else self.fs.unstrip_protocol(path)

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
