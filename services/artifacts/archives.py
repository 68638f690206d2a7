"""Unpacking an uploaded zip or tar(.gz) into a Staging, refusing what an archive can hide.

Only regular files are taken: symlinks, hardlinks, devices and fifos are refused, and names
are checked by the staging like any upload. Decompression bombs are refused from the declared
sizes before a member is read and again from the bytes actually produced while reading.
"""

from __future__ import annotations

import gzip
import lzma
import stat
import tarfile
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path, PurePosixPath
from typing import BinaryIO

from services.artifacts.paths import printable
from services.artifacts.staging import PAYLOAD_TOO_LARGE, Staging, UploadError, UploadLimits
from services.artifacts.store import read_chunks

# Below this many bytes the ratio is not judged: small, repetitive files compress very well.
RATIO_FLOOR_BYTES = 1 << 20
_TAR_MODES = {".tar": "r|", ".tar.gz": "r|gz", ".tgz": "r|gz"}
_ZIP_SUFFIX = ".zip"
_ZIP_ENCRYPTED = 0x1


def is_archive(name: str) -> bool:
    return _suffix(name) is not None


def _suffix(name: str) -> str | None:
    lowered = name.lower()
    return next((s for s in (_ZIP_SUFFIX, *_TAR_MODES) if lowered.endswith(s)), None)


def _skipped(name: str) -> bool:
    """Operating-system litter that archivers add (macOS resource forks and folder settings)."""
    path = PurePosixPath(name)
    return path.parts[:1] == ("__MACOSX",) or path.name == ".DS_Store"


class _InflationGuard:
    """Refuses an archive whose members expand more than the allowed ratio over its own size."""

    def __init__(self, archive_name: str, archive_bytes: int, limits: UploadLimits):
        self.archive_name = archive_name
        self.ratio = limits.max_compression_ratio
        self.allowed = max(self.ratio * archive_bytes, RATIO_FLOOR_BYTES)
        self.total = 0

    def check_declared(self, name: str, declared: int, compressed: int) -> None:
        if declared > max(self.ratio * compressed, RATIO_FLOOR_BYTES):
            raise UploadError(
                name,
                f"declares {declared} bytes from {compressed} compressed (more than {self.ratio:g}:1); "
                "refusing a likely decompression bomb",
                PAYLOAD_TOO_LARGE,
            )

    def count(self, name: str, chunks: Iterable[bytes]) -> Iterator[bytes]:
        for chunk in chunks:
            self.total += len(chunk)
            if self.total > self.allowed:
                raise UploadError(
                    name,
                    f"{self.archive_name} expands to more than {self.ratio:g} times its size; "
                    "refusing a likely decompression bomb",
                    PAYLOAD_TOO_LARGE,
                )
            yield chunk


def extract_archive(path: Path, name: str, staging: Staging) -> None:
    """Stage every regular file of the archive at `path` (uploaded as `name`)."""
    suffix = _suffix(name)
    guard = _InflationGuard(name, path.stat().st_size, staging.limits)
    try:
        if suffix == _ZIP_SUFFIX:
            _extract_zip(path, staging, guard)
        else:
            _extract_tar(path, _TAR_MODES[suffix], staging, guard)
    # NotImplementedError: zipfile has no decompressor for the member's compression method
    except (
        zipfile.BadZipFile,
        tarfile.TarError,
        gzip.BadGzipFile,
        zlib.error,
        EOFError,
        NotImplementedError,
    ) as error:
        raise UploadError(name, f"cannot read the archive: {error}") from None
    except UnicodeDecodeError as error:  # a zip member flagged UTF-8 with a name that is not UTF-8
        member = printable(bytes(error.object).decode("utf-8", "surrogateescape"))
        raise UploadError(member, "the file name is not valid UTF-8 (the archive says it is)") from None


def _extract_zip(path: Path, staging: Staging, guard: _InflationGuard) -> None:
    limits = staging.limits
    with zipfile.ZipFile(path) as archive:
        # not `ZipInfo.is_dir()`, which raises IndexError on a member with an empty name
        members = [m for m in archive.infolist() if not m.filename.endswith("/") and not _skipped(m.filename)]
        if len(members) > limits.max_files:
            raise UploadError(
                guard.archive_name,
                f"too many files: {len(members)}, at most {limits.max_files} per upload",
                PAYLOAD_TOO_LARGE,
            )
        declared_total = sum(m.file_size for m in members)
        if declared_total > limits.max_total_bytes:
            raise UploadError(
                guard.archive_name,
                f"declares {declared_total} bytes, over the limit of {limits.max_total_bytes} bytes in total",
                PAYLOAD_TOO_LARGE,
            )
        for member in members:
            if stat.S_IFMT(member.external_attr >> 16) not in (0, stat.S_IFREG):
                raise UploadError(member.filename, "symlinks and special files are not allowed in archives")
            if member.flag_bits & _ZIP_ENCRYPTED:
                raise UploadError(member.filename, "encrypted archive members are not supported")
            guard.check_declared(member.filename, member.file_size, member.compress_size)
            if member.header_offset < 0:  # zipfile would seek before the archive's start (OSError)
                raise zipfile.BadZipFile(f"{member.filename}: its header lies before the archive's start")
            with archive.open(member) as stream:
                chunks = guard.count(member.filename, _decompressed(member.filename, stream))
                staging.add(member.filename, chunks, declared_size=member.file_size)


def _decompressed(name: str, stream: BinaryIO) -> Iterator[bytes]:
    """A zip member's bytes; its decompressor's errors on corrupt data (bz2 raises a bare OSError, lzma
    an LZMAError) are the archive's (zlib's are caught by `extract_archive`)."""
    try:
        yield from read_chunks(stream)
    except (OSError, lzma.LZMAError) as error:
        raise zipfile.BadZipFile(f"{name}: {error}") from None


def _extract_tar(path: Path, mode: str, staging: Staging, guard: _InflationGuard) -> None:
    try:  # stream mode: members are read in order, never seeked
        archive = tarfile.open(path, mode)  # noqa: SIM115  (closed by the `with` below)
    except TypeError:  # tarfile reads a gzip header cut short as ord(b"")
        raise tarfile.ReadError("the gzip header is cut short") from None
    with archive:
        for member in archive:
            if member.isdir() or _skipped(member.name):
                continue
            if member.issym() or member.islnk():
                raise UploadError(member.name, "symlinks and hardlinks are not allowed in archives")
            if not member.isreg():
                raise UploadError(member.name, "devices, fifos and other special files are not allowed")
            stream = archive.extractfile(member)
            chunks = guard.count(member.name, read_chunks(stream))
            staging.add(member.name, chunks, declared_size=member.size)
