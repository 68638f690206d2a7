"""Scene materials that name a model in the store (`artifact: sha256:...`; `workers.scene.format.spec`'s
`AggregateMaterial`) instead of a folder of the upload, so a pipeline that trained one (a `mesogan` job)
renders it in any number of scenes without uploading it again.

At each submission the artifact must exist, be the submitting tenant's, and be of the kind that draws the
material (`workers.models.registry.material_kind`); an id that does not exist and another tenant's get the
same answer, so ids cannot be probed. When the job starts, the artifact's files join the scene's under
`.artifacts/<hex>/` of its folder (`workers.scene.portability.stored.artifact_folder`): a worker on any node
fetches them by digest with the scene's own files (`StoredScene`), and the material loads them from there.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

from services.artifacts.artifacts import ArtifactNotFound, ArtifactStore
from services.jobs.tenants import Tenancy
from services.platform.auth import Principal
from services.platform.errors import InvalidInput
from workers.models.registry import material_kind
from workers.scene.format.spec import AggregateMaterial, SceneSpec
from workers.scene.portability.stored import StoredFile, artifact_folder

KINDS_CACHE_SIZE = 4096  # artifact id -> kind; a manifest never changes, so a repeated submission reads none


def named_artifacts(spec: SceneSpec) -> dict[str, AggregateMaterial]:
    """The materials of `spec` that name a stored artifact, by name (used by an object or not, as a `path`
    is checked at upload whether used or not)."""
    return {
        name: material
        for name, material in spec.materials.items()
        if isinstance(material, AggregateMaterial) and material.artifact is not None
    }


class MaterialArtifacts:
    """The store's artifacts as scene materials name them; with `tenancy`, only the caller's tenant's."""

    def __init__(self, artifacts: ArtifactStore, tenancy: Tenancy | None = None):
        self.artifacts, self.tenancy = artifacts, tenancy
        self._kinds: OrderedDict[str, str] = OrderedDict()
        self._kinds_lock = threading.Lock()

    def check(self, spec: SceneSpec, principal: Principal | None) -> None:
        """InvalidInput naming `scene.materials.<name>.artifact` for an artifact the caller cannot use."""
        for name, material in named_artifacts(spec).items():
            field, artifact_id = f"scene.materials.{name}.artifact", material.artifact
            kind = self._kind(artifact_id) if self._visible(artifact_id, principal) else None
            if kind is None:
                problem = f"no artifact {artifact_id!r}: name an artifact id your finished jobs report"
                raise InvalidInput(problem, field)
            if kind != (drawn := material_kind(material.type)):
                problem = (
                    f"{artifact_id} is a {kind!r} artifact: a {material.type} material draws a {drawn!r} one"
                )
                raise InvalidInput(problem, field)

    def files(self, spec: SceneSpec) -> dict[str, StoredFile]:
        """The files of the artifacts `spec`'s materials name, by their names in the job's scene folder."""
        files = {}
        for artifact_id in sorted({m.artifact for m in named_artifacts(spec).values()}):
            folder = artifact_folder(artifact_id)
            for entry in self.artifacts.manifest(artifact_id).files:
                url = self.artifacts.blobs.blob_url(entry.digest)
                files[f"{folder}/{entry.name}"] = StoredFile(url=url, digest=entry.digest)
        return files

    def _visible(self, artifact_id: str, principal: Principal | None) -> bool:
        return self.tenancy is None or principal is None or self.tenancy.sees_artifact(principal, artifact_id)

    def _kind(self, artifact_id: str) -> str | None:
        """The stored artifact's kind, from its manifest (None: no such artifact)."""
        with self._kinds_lock:
            if (kind := self._kinds.get(artifact_id)) is not None:
                self._kinds.move_to_end(artifact_id)
                return kind
        try:
            kind = self.artifacts.manifest(artifact_id).kind
        except ArtifactNotFound:
            return None
        with self._kinds_lock:
            self._kinds[artifact_id] = kind
            while len(self._kinds) > KINDS_CACHE_SIZE:
                self._kinds.popitem(last=False)
        return kind
