"""Content-addressed records: the file entry, and the artifact manifest (OCI-style).

A record's id is the digest of its canonical JSON without the id itself, so a record read
back can be checked against the id it was asked for, and equal content gets an equal id.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Annotated, Any, ClassVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field

from services.artifacts.digests import canonical_json, digest_json, parse_digest
from services.artifacts.media_types import media_type_for
from services.artifacts.store import BlobStore

ARTIFACT_MEDIA_TYPE = "application/vnd.neuralbake.artifact.v1+json"
# The pipeline's report files (`workers.runtime.report`): they hold measured timings, which differ between
# runs of the same job, so the model digest leaves them out.
MEASUREMENT_FILES = frozenset({"report.json", "speed_error.png"})
MODEL_DIGEST = "model_digest"  # the annotation every published manifest carries
_PLACEHOLDER_ID = "sha256:" + "0" * 64


def _digest(value: str) -> str:
    parse_digest(value)
    return value


Digest = Annotated[str, AfterValidator(_digest)]


class FileEntry(BaseModel):
    """One stored file: `name` is its path inside the artifact or asset."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(min_length=1)
    media_type: str
    digest: Digest
    size: int = Field(ge=0)


def store_file(blobs: BlobStore, name: str, path: str | Path, media_type: str = "") -> FileEntry:
    """Put the file at `path` into `blobs` as `name` (media type inferred from the name if not given)."""
    digest = blobs.put_file(path)
    return FileEntry(
        name=name, media_type=media_type or media_type_for(name), digest=digest, size=blobs.size(digest)
    )


def model_digest(files: list[FileEntry]) -> str:
    """The digest of an artifact's model: its file entries but `MEASUREMENT_FILES`. The artifact id also
    covers the job, its time and its (timed) metrics; equal jobs (kind, scene, config, seed, code) store
    equal models, and this is what says so."""
    kept = [entry.model_dump(mode="json") for entry in files if entry.name not in MEASUREMENT_FILES]
    return digest_json(sorted(kept, key=lambda entry: entry["name"]))


class ContentAddressed(BaseModel):
    """A record whose `id_field` is the digest of the canonical JSON of its other (hashed) fields."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    id_field: ClassVar[str]
    unhashed: ClassVar[frozenset[str]] = frozenset()  # fields that may differ between equal records

    @classmethod
    def build(cls, **fields: Any):
        """The record with its id computed from `fields`."""
        draft = cls(**{cls.id_field: _PLACEHOLDER_ID}, **fields)
        return draft.model_copy(update={cls.id_field: draft.computed_id()})

    def content(self) -> dict[str, Any]:
        return self.model_dump(mode="json", exclude={self.id_field, *self.unhashed})

    def canonical_bytes(self) -> bytes:
        return canonical_json(self.content())

    def computed_id(self) -> str:
        return digest_json(self.content())

    def is_intact(self) -> bool:
        return getattr(self, self.id_field) == self.computed_id()


class Manifest(ContentAddressed):
    """What an artifact holds and where it came from; every field is covered by the id."""

    id_field: ClassVar[str] = "artifact_id"

    schema_version: int = 2
    media_type: str = ARTIFACT_MEDIA_TYPE
    artifact_id: Digest
    kind: str
    job_id: str
    scene_hash: str
    config: dict[str, Any]
    code_version: str
    metrics: dict[str, float]
    created: datetime
    files: list[FileEntry]
    annotations: dict[str, str] = Field(default_factory=dict)

    def file(self, name: str) -> FileEntry | None:
        return next((entry for entry in self.files if entry.name == name), None)
