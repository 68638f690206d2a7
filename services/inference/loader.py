"""Fetching an artifact from the store by id and loading it through its kind's `infer`.

The manifest is read from its own blob (so it matches the id), and every file is downloaded verified:
a file whose bytes do not match the manifest's digest refuses the whole artifact before any of it is
handed to a model, so a corrupted artifact is never served.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.store import BlobCorrupted, BlobNotFound
from services.inference.errors import ArtifactRefused, UnsupportedOperation
from workers.models.registry import Inference, LoadedModel, UnknownKind, get_inference


@dataclass
class Loaded:
    artifact_id: str
    kind: str
    inference: Inference
    model: LoadedModel
    device: str

    @property
    def nbytes(self) -> int:
        return int(self.model.nbytes)


def load_artifact(artifacts: ArtifactStore, artifact_id: str, device: str, work_dir: Path) -> Loaded:
    """ArtifactNotFound for an unknown id; ArtifactRefused for one that fails verification."""
    try:
        manifest = artifacts.manifest(artifact_id)
        inference = get_inference(manifest.kind)
    except BlobCorrupted as error:
        raise ArtifactRefused(f"the manifest of {artifact_id} is corrupted ({error}); not loaded") from None
    except UnknownKind as error:
        raise UnsupportedOperation(f"{artifact_id}: {error}") from None
    if inference is None:
        raise UnsupportedOperation(
            f"{artifact_id} is a {manifest.kind!r} artifact; that kind cannot be served"
        )
    work_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="artifact-", dir=work_dir) as folder:
        for entry in manifest.files:
            try:
                artifacts.blobs.download(entry.digest, Path(folder) / entry.name)
            except BlobCorrupted as error:
                raise ArtifactRefused(
                    f"file {entry.name!r} of {artifact_id} does not match its digest {entry.digest} "
                    f"(the store holds {error.actual}); the artifact was not loaded"
                ) from None
            except BlobNotFound:
                raise ArtifactRefused(
                    f"file {entry.name!r} of {artifact_id} ({entry.digest}) is missing from the store; "
                    "the artifact was not loaded"
                ) from None
        model = inference.load(Path(folder), device)
    return Loaded(artifact_id, manifest.kind, inference, model, device)
