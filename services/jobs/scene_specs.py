"""Resolved scenes stored once: a job row names its SceneSpec by the digest of the spec's canonical JSON,
and the JSON itself is a blob of the artifact store (local or S3, beside assets and artifacts). A forced
resubmission of a large scene (a 100k-instance USD instancer expands to 15 MB) adds a row of a few hundred
bytes to the job database instead of the scene again, and any node that reads the store reads the scene.

A blob collector must keep these blobs while a job names them: pass the jobs' `scene_digest`s in
`ArtifactStore.gc_blobs`'s `keep`.
"""

from __future__ import annotations

import json
from typing import Any

from services.artifacts.digests import digest_bytes
from services.artifacts.store import BlobStore
from services.jobs.identity import canonical_json


def spec_digest(spec_json: dict[str, Any]) -> str:
    """The digest a scene's JSON (`SceneSpec.model_dump(mode="json")`) is stored under."""
    return digest_bytes(canonical_json(spec_json))


class SceneSpecs:
    """SceneSpec JSON by digest, in `blobs`."""

    def __init__(self, blobs: BlobStore):
        self.blobs = blobs

    def put(self, spec_json: dict[str, Any]) -> str:
        """Store the scene (once: content already there is not written again); its digest."""
        return self.blobs.put_bytes(canonical_json(spec_json))

    def contains(self, digest: str) -> bool:
        return self.blobs.exists(digest)

    def get(self, digest: str) -> dict[str, Any]:
        """The scene's JSON, verified against its digest; BlobNotFound (a LookupError) when absent."""
        return json.loads(self.blobs.read(digest))
