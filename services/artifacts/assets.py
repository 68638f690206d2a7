"""Uploaded scenes as assets: a content-addressed listing of files, saved under `<root>/assets/`.

The id covers the file names, digests and the scene file but not the upload time, so the same
files uploaded twice (loose, zipped or tarred) are one asset.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import ClassVar

import fsspec
from pydantic import ValidationError

from services.artifacts.digests import parse_digest
from services.artifacts.manifest import ContentAddressed, Digest, FileEntry
from services.artifacts.paths import safe_relative_path
from services.artifacts.store import BlobCorrupted, BlobStore, indexed_digests, write_atomic


class AssetNotFound(LookupError):
    def __init__(self, asset_id: str):
        self.asset_id = asset_id
        super().__init__(f"asset not found: {asset_id}")


class Asset(ContentAddressed):
    id_field: ClassVar[str] = "asset_id"
    unhashed: ClassVar[frozenset[str]] = frozenset({"created"})

    asset_id: Digest
    scene_file: str  # path of the scene file inside the asset
    scene_name: str
    files: list[FileEntry]  # sorted by name; name = relative path inside the asset
    created: datetime

    @classmethod
    def from_files(cls, scene_file: str, scene_name: str, files: list[FileEntry]) -> Asset:
        return cls.build(
            scene_file=scene_file,
            scene_name=scene_name,
            files=sorted(files, key=lambda entry: entry.name),
            created=datetime.now(UTC),
        )


def _listing_path(asset_id: str, root_url: str) -> tuple[fsspec.AbstractFileSystem, str]:
    fs, root = fsspec.core.url_to_fs(str(root_url))
    return fs, f"{root.rstrip('/')}/assets/{parse_digest(asset_id)}.json"


def save_asset(asset: Asset, blobs: BlobStore, root_url: str) -> None:
    """Record the listing (its files must already be in `blobs`); the first upload's time is kept."""
    if not asset.is_intact():
        raise ValueError(f"asset id {asset.asset_id} does not match its listing ({asset.computed_id()})")
    missing = [entry.name for entry in asset.files if not blobs.exists(entry.digest)]
    if missing:
        raise ValueError(f"asset files are not in the blob store: {', '.join(missing)}")
    fs, path = _listing_path(asset.asset_id, root_url)
    if not fs.exists(path):
        write_atomic(fs, path, [asset.model_dump_json(indent=2).encode()])


def load_asset(asset_id: str, root_url: str) -> Asset:
    """The saved listing, checked against its id (BlobCorrupted if it was altered); AssetNotFound."""
    fs, path = _listing_path(asset_id, root_url)
    try:
        text = fs.cat_file(path)
    except FileNotFoundError:
        raise AssetNotFound(asset_id) from None
    try:
        asset = Asset.model_validate_json(text)
    except ValidationError as error:
        raise BlobCorrupted(asset_id, f"an unreadable listing ({error.error_count()} errors)") from None
    if asset.asset_id != asset_id or not asset.is_intact():
        raise BlobCorrupted(asset_id, asset.computed_id())
    return asset


def asset_ids(root_url: str) -> list[str]:
    """Every saved asset id."""
    fs, root = fsspec.core.url_to_fs(str(root_url))
    return indexed_digests(fs, f"{root.rstrip('/')}/assets")


def materialize(asset: Asset, blobs: BlobStore, dest_dir: Path) -> Path:
    """Write the asset's files under `dest_dir` (verified; names re-checked); the scene file's path."""
    dest_dir = Path(dest_dir)
    for entry in asset.files:
        blobs.download(entry.digest, dest_dir / safe_relative_path(entry.name))
    return dest_dir / safe_relative_path(asset.scene_file)
