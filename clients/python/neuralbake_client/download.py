"""Downloading an artifact's files so that an interrupted download resumes and a finished one is known
good: bytes go to `<name>.part`, a later attempt asks for the rest from the part's size, and only a file
whose sha256 matches the manifest is renamed into place.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Protocol

from neuralbake_client.errors import ChecksumMismatch, NeuralbakeError
from neuralbake_client.models import FileEntry
from neuralbake_client.retry import Retry

PART_SUFFIX = ".part"


class FileSource(Protocol):
    def read_file(self, artifact_id: str, name: str, digest: str, offset: int) -> Iterator[bytes]: ...


@dataclass(frozen=True)
class DownloadedFile:
    path: Path
    entry: FileEntry
    resumed_from: int  # bytes already on disk from an earlier, interrupted attempt (0: fresh)
    skipped: bool = False  # the file was already there with the right digest


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        while chunk := stream.read(1 << 20):
            digest.update(chunk)
    return "sha256:" + digest.hexdigest()


def target_path(dest: Path, name: str) -> Path:
    """Where a file of the artifact goes; a name that would escape `dest` is refused."""
    relative = PurePosixPath(name)
    if relative.is_absolute() or ".." in relative.parts or not relative.parts:
        raise NeuralbakeError(f"refusing the artifact file name {name!r}: it leaves the destination folder")
    return dest.joinpath(*relative.parts)


def download_file(
    source: FileSource,
    artifact_id: str,
    entry: FileEntry,
    dest: Path,
    retry: Retry,
    on_bytes: Callable[[int], None] | None = None,
) -> DownloadedFile:
    target = target_path(dest, entry.name)
    if target.is_file() and target.stat().st_size == entry.size and sha256_of(target) == entry.digest:
        return DownloadedFile(target, entry, 0, skipped=True)
    target.parent.mkdir(parents=True, exist_ok=True)
    part = target.with_name(target.name + PART_SUFFIX)
    resumed_from = part.stat().st_size if part.is_file() else 0
    if resumed_from > entry.size:
        part.unlink()
        resumed_from = 0

    def fetch() -> None:
        offset = part.stat().st_size if part.is_file() else 0
        if offset >= entry.size:
            return
        with part.open("ab") as out:
            for chunk in source.read_file(artifact_id, entry.name, entry.digest, offset):
                out.write(chunk)
                if on_bytes:
                    on_bytes(len(chunk))

    retry.call(fetch)
    if sha256_of(part) != entry.digest:
        part.unlink()
        if not resumed_from:
            raise ChecksumMismatch(f"{entry.name}: the downloaded bytes do not match {entry.digest}")
        retry.call(fetch)  # the kept part was bad: once more from the start
        if sha256_of(part) != entry.digest:
            part.unlink()
            raise ChecksumMismatch(f"{entry.name}: the downloaded bytes do not match {entry.digest}")
    part.replace(target)
    return DownloadedFile(target, entry, resumed_from)
