"""Media types for artifact and asset files, by extension (OCI manifests name one per file)."""

from __future__ import annotations

from pathlib import PurePosixPath

DEFAULT_MEDIA_TYPE = "application/octet-stream"

_BY_SUFFIX = {
    ".exr": "image/x-exr",
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".jpeg": "image/jpeg",
    ".hdr": "image/vnd.radiance",
    ".json": "application/json",
    ".yaml": "application/yaml",
    ".yml": "application/yaml",
    ".safetensors": "application/vnd.safetensors",
    ".obj": "model/obj",
    ".mtl": "model/mtl",
    ".ply": "model/x-ply",
    ".stl": "model/stl",
    ".glb": "model/gltf-binary",
    ".gltf": "model/gltf+json",
    ".txt": "text/plain",
    ".csv": "text/csv",
}


MEDIA_TYPES = sorted({DEFAULT_MEDIA_TYPE, *_BY_SUFFIX.values()})  # what a file download may answer with


def media_type_for(name: str) -> str:
    """The media type for a file name (case-insensitive suffix); unknown suffixes are octet streams."""
    return _BY_SUFFIX.get(PurePosixPath(name).suffix.lower(), DEFAULT_MEDIA_TYPE)
