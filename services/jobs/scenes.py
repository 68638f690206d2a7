"""The three ways a job names its scene (an uploaded asset id, a built-in name, an inline SceneSpec),
resolved to one validated SceneSpec, a content hash, and (for assets) a folder holding its files; the
stored artifacts its materials name are checked for the caller and join the files a job fetches.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.artifacts.artifacts import ArtifactStore
from services.artifacts.assets import AssetNotFound, load_asset, materialize
from services.artifacts.store import BlobStore
from services.artifacts.validation import file_references
from services.jobs.identity import scene_hash, sha256_of
from services.jobs.material_artifacts import MaterialArtifacts, named_artifacts
from services.jobs.scene_specs import SceneSpecs, spec_digest
from services.jobs.tenants import Tenancy
from services.platform.auth import Principal
from services.platform.errors import InvalidInput
from workers.scene.format.errors import SceneError
from workers.scene.format.spec import SceneSpec
from workers.scene.generators.builtin import BUILTIN_SCENES, get_builtin
from workers.scene.portability.io import check_nesting, load_scene, scene_from_dict
from workers.scene.portability.stored import ARTIFACTS_FOLDER, StoredFile, StoredScene

ASSET_PREFIX = "sha256:"
if TYPE_CHECKING:
    from services.geometry import GeometryProcesses

RESOLVED_CACHE_SIZE = 512  # resolved scenes (a spec of a few KB each) kept for repeated submissions


@dataclass(frozen=True)
class ResolvedScene:
    """Shared between the submissions that name the same scene: read it, never change it."""

    spec: SceneSpec
    ref: dict[str, str]  # {"source": "builtin" | "asset" | "inline", "name": ..., "asset_id": ...}
    content_hash: str
    spec_json: dict[str, Any]  # spec.model_dump(mode="json"), as stored in the artifact store
    spec_digest: str  # what the job row holds: the stored spec_json's digest (`services.jobs.scene_specs`)


def scene_field(error: SceneError) -> str:
    """A SceneError's dotted field, as a path inside the job body."""
    return "scene" if error.field in ("scene", "") else f"scene.{error.field}"


class SceneResolver:
    """Reads assets from the store; their files are unpacked once into `cache_dir/<hex>` and reused, and
    parsed in `geometry`'s child processes when given. With `tenancy`, an asset, and a stored artifact a
    material names, resolve only for a caller whose tenant sees them.

    Resolutions are cached: a built-in name and an asset id (content-addressed, never rewritten) always
    resolve to the same scene, and an inline scene is keyed by the hash of its canonical JSON. A repeated
    submission then costs no validation, no store read and no hashing of the scene (they were 2 of a
    submission's 8 ms on SQLite). The tenant checks are made at every resolution, so the cache never
    answers for an asset or a material's artifact the caller does not see.
    """

    def __init__(
        self,
        blobs: BlobStore,
        assets_root: str,
        cache_dir: Path,
        tenancy: Tenancy | None = None,
        geometry: GeometryProcesses | None = None,
    ):
        self.blobs, self.assets_root, self.cache_dir = blobs, assets_root, cache_dir
        self.tenancy, self.geometry = tenancy, geometry
        self.material_artifacts = MaterialArtifacts(ArtifactStore(blobs, assets_root), tenancy)
        self.specs = SceneSpecs(blobs)
        self._resolved: OrderedDict[str, ResolvedScene] = OrderedDict()
        self._resolved_lock = threading.Lock()

    def resolve(self, scene: str | dict[str, Any], principal: Principal | None = None) -> ResolvedScene:
        """InvalidInput naming the field for an unknown name or asset (another tenant's included) and for
        any problem in the scene."""
        if isinstance(scene, str) and not self._visible(scene, principal):  # before anything is read
            raise InvalidInput(f"no asset {scene!r}; upload it with POST /v1/assets first", "scene")
        key = scene if isinstance(scene, str) else _inline_key(scene)
        with self._resolved_lock:
            if (resolved := self._resolved.get(key)) is not None:
                self._resolved.move_to_end(key)
        if resolved is None:
            resolved = self._resolve(scene)
            with self._resolved_lock:
                self._resolved[key] = resolved
                while len(self._resolved) > RESOLVED_CACHE_SIZE:
                    self._resolved.popitem(last=False)
        self.material_artifacts.check(resolved.spec, principal)
        return resolved

    def _resolve(self, scene: str | dict[str, Any]) -> ResolvedScene:
        try:
            if isinstance(scene, dict):
                spec = scene_from_dict(scene)
                for field, path in file_references(spec.model_dump(mode="json", exclude_none=True)):
                    raise SceneError(
                        field, f"an inline scene cannot name files ({path!r}): upload it as an asset"
                    )
                return _resolved(spec, {"source": "inline", "name": spec.name}, {})
            if scene.startswith(ASSET_PREFIX):
                return self._asset(scene)
            if scene not in BUILTIN_SCENES:
                known = ", ".join(sorted(BUILTIN_SCENES))
                raise InvalidInput(
                    f"{scene!r} is neither an asset id (sha256:...) nor a built-in scene ({known})", "scene"
                )
            spec = get_builtin(scene)
            return _resolved(spec, {"source": "builtin", "name": scene}, {})
        except SceneError as error:
            raise InvalidInput(error.problem, scene_field(error)) from None

    def store(self, resolved: ResolvedScene) -> str:
        """Put the scene's spec in the store unless it is there already (a repeat is a look-up, not a
        write of the whole scene); the digest a job row names it by."""
        if not self.specs.contains(resolved.spec_digest):
            self.specs.put(resolved.spec_json)
        return resolved.spec_digest

    def scene_dir(self, ref: dict[str, str]) -> Path | None:
        """The folder a driver resolves the scene's relative paths against (None without files)."""
        return self._materialized(ref["asset_id"])[0] if ref["source"] == "asset" else None

    def stored_files(self, ref: dict[str, str], scene: dict[str, Any]) -> StoredScene | None:
        """The files of the scene `ref` names (`scene`: its spec's JSON) as a driver on any
        node fetches them: store URLs and digests, the stored artifacts its materials name included (None
        without files). The cache folder is the asset's, or named by the files' content with artifacts."""
        files = {}
        if ref["source"] == "asset":
            for entry in load_asset(ref["asset_id"], self.assets_root).files:
                files[entry.name] = StoredFile(url=self.blobs.blob_url(entry.digest), digest=entry.digest)
        artifacts = self.material_artifacts.files(SceneSpec.model_validate(scene))
        if not artifacts:
            return StoredScene(key=ref["asset_id"].removeprefix(ASSET_PREFIX), files=files) if files else None
        files |= artifacts
        key = sha256_of({name: stored.digest for name, stored in files.items()}).removeprefix("sha256:")
        return StoredScene(key=key, files=files)

    def _visible(self, scene: str, principal: Principal | None) -> bool:
        """Whether `principal`'s tenant sees `scene` when it names an asset (built-in names: always)."""
        if not scene.startswith(ASSET_PREFIX) or self.tenancy is None or principal is None:
            return True
        return self.tenancy.sees_asset(principal, scene)

    def _asset(self, asset_id: str) -> ResolvedScene:
        try:
            asset = load_asset(asset_id, self.assets_root)
        except (AssetNotFound, ValueError):
            raise InvalidInput(
                f"no asset {asset_id!r}; upload it with POST /v1/assets first", "scene"
            ) from None
        _, scene_file = self._materialized(asset_id, asset)
        if self.geometry is None:
            spec, _ = load_scene(scene_file)
        else:  # a server: an uploaded file is read in a child process, as at upload
            spec, _ = self.geometry.run(asset.scene_file, load_scene, scene_file)
        named = list(named_artifacts(spec))
        if named and any(entry.name.startswith(f"{ARTIFACTS_FOLDER}/") for entry in asset.files):
            raise SceneError(
                f"materials.{named[0]}.artifact",
                f"the upload has a {ARTIFACTS_FOLDER}/ folder, where a job puts the stored artifacts its "
                "materials name: rename that folder",
            )
        files = {entry.name: entry.digest for entry in asset.files}
        ref = {"source": "asset", "name": asset.scene_name, "asset_id": asset_id}
        return _resolved(spec, ref, files)

    def _materialized(self, asset_id: str, asset=None) -> tuple[Path, Path]:
        """(folder, scene file); unpacked into a temporary folder and renamed, so readers never see half."""
        asset = asset or load_asset(asset_id, self.assets_root)
        folder = self.cache_dir / asset_id.removeprefix(ASSET_PREFIX)
        if not folder.is_dir():
            self.cache_dir.mkdir(parents=True, exist_ok=True)
            staging = Path(tempfile.mkdtemp(prefix=".unpack-", dir=self.cache_dir))
            materialize(asset, self.blobs, staging)
            try:
                os.rename(staging, folder)
            except OSError:  # another request unpacked the same asset first
                shutil.rmtree(staging, ignore_errors=True)
        return folder, folder / asset.scene_file


def _inline_key(scene: dict[str, Any]) -> str:
    """The cache key of an inline scene: its canonical JSON's hash (bounded in depth before it is walked)."""
    try:
        check_nesting(scene, "scene")
    except SceneError as error:
        raise InvalidInput(error.problem, scene_field(error)) from None
    return "inline:" + sha256_of(scene)


def _resolved(spec: SceneSpec, ref: dict[str, str], files: dict[str, str]) -> ResolvedScene:
    spec_json = spec.model_dump(mode="json")
    return ResolvedScene(spec, ref, scene_hash(spec_json, files), spec_json, spec_digest(spec_json))
