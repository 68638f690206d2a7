"""Zip and tar(.gz) uploads built in memory: (archive name, stream) parts as `ingest_upload` takes them."""

from __future__ import annotations

import io
import tarfile
import zipfile


def zipped(files: dict[str, bytes], name: str = "scene.zip") -> list[tuple[str, io.BytesIO]]:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for member, data in files.items():
            archive.writestr(member, data)
    return [(name, io.BytesIO(buffer.getvalue()))]


def tarred(
    files: dict[str, bytes], name: str = "scene.tar.gz", links: dict[str, tuple[bytes, str]] | None = None
) -> list[tuple[str, io.BytesIO]]:
    """A tar(.gz) of `files`; `links` adds members of another type: name -> (tarfile type, target)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz" if name.endswith("gz") else "w") as archive:
        for member, data in files.items():
            info = tarfile.TarInfo(member)
            info.size = len(data)
            archive.addfile(info, io.BytesIO(data))
        for member, (kind, target) in (links or {}).items():
            info = tarfile.TarInfo(member)
            info.type, info.linkname = kind, target
            archive.addfile(info)
    return [(name, io.BytesIO(buffer.getvalue()))]
