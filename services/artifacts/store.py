"""A content-addressed blob store over fsspec: `<root>/blobs/sha256/ab/cdef...`.

Writes go to a temporary name in the blob's own directory and are renamed into place, so a
reader never sees a partial blob and concurrent puts of the same content are harmless (both
renames install identical bytes). Every full read is checked against the digest, because the
address is the only thing that vouches for the content.
"""

from __future__ import annotations

import contextlib
import hashlib
import re
import uuid
from collections.abc import Iterable, Iterator
from datetime import datetime
from pathlib import Path
from typing import BinaryIO

import fsspec
from fsspec.implementations.local import LocalFileSystem

from services.artifacts.digests import digest_bytes, format_digest, parse_digest

CHUNK_BYTES = 1 << 20
_INDEX_NAME = re.compile(r"[0-9a-f]{64}\.json")


class BlobNotFound(LookupError):
    """No blob is stored under this digest."""

    def __init__(self, digest: str):
        self.digest = digest
        super().__init__(f"blob not found: {digest}")


class BlobCorrupted(Exception):
    """Stored content does not hash to its address: the store was damaged, not the request."""

    def __init__(self, digest: str, actual: str):
        self.digest = digest
        self.actual = actual
        super().__init__(f"stored content for {digest} hashes to {actual}")


def hash_chunks(chunks: Iterable[bytes]) -> tuple[str, int]:
    """(digest, size) of a stream of chunks."""
    hasher, size = hashlib.sha256(), 0
    for chunk in chunks:
        hasher.update(chunk)
        size += len(chunk)
    return format_digest(hasher.hexdigest()), size


def copy_hashed(chunks: Iterable[bytes], out: BinaryIO) -> str:
    """Write `chunks` to `out`; the digest of what was written."""
    hasher = hashlib.sha256()
    for chunk in chunks:
        hasher.update(chunk)
        out.write(chunk)
    return format_digest(hasher.hexdigest())


def write_atomic(fs, path: str, chunks: Iterable[bytes], expected_digest: str | None = None) -> None:
    """Write to a unique temporary name beside `path`, then rename into place.

    With `expected_digest`, content that hashes otherwise (a source changed while it was
    copied) raises BlobCorrupted and `path` is left untouched.
    """
    fs.makedirs(path.rsplit("/", 1)[0], exist_ok=True)
    temporary = f"{path}.tmp-{uuid.uuid4().hex}"
    try:
        with fs.open(temporary, "wb") as out:
            written = copy_hashed(chunks, out)
        if expected_digest is not None and written != expected_digest:
            raise BlobCorrupted(expected_digest, written)
        fs.mv(temporary, path)
    finally:
        if fs.exists(temporary):
            fs.rm(temporary)


def indexed_digests(fs, folder: str) -> list[str]:
    """The digests named by `<hex>.json` files in `folder` (an index of manifests or assets)."""
    if not fs.exists(folder):
        return []
    names = [path.rsplit("/", 1)[-1] for path in fs.ls(folder, detail=False)]
    return sorted(format_digest(n.removesuffix(".json")) for n in names if _INDEX_NAME.fullmatch(n))


def read_chunks(stream: BinaryIO) -> Iterator[bytes]:
    while chunk := stream.read(CHUNK_BYTES):
        yield chunk


class BlobStore:
    """Blobs addressed by sha256 under `url` ("file:///abs", a plain path, or "s3://bucket/prefix")."""

    def __init__(self, url: str):
        self.url = url
        self.fs, self.root = fsspec.core.url_to_fs(str(url))
        self.root = self.root.rstrip("/")

    # ------------------------------------------------------------------ writing

    def put_bytes(self, data: bytes) -> str:
        digest = digest_bytes(data)
        if not self._present(digest, len(data)):
            self._install(digest, [data])
        return digest

    def put_file(self, path: str | Path) -> str:
        """Hash, then copy (hashing again, so a file changed in between is caught rather than stored)."""
        with open(path, "rb") as stream:
            digest, size = hash_chunks(read_chunks(stream))
        if not self._present(digest, size):
            with open(path, "rb") as stream:
                self._install(digest, read_chunks(stream))
        return digest

    def _present(self, digest: str, size: int) -> bool:
        path = self._path(digest)
        try:
            return self.fs.size(path) == size
        except FileNotFoundError:
            return False

    def _install(self, digest: str, chunks: Iterable[bytes]) -> None:
        write_atomic(self.fs, self._path(digest), chunks, expected_digest=digest)

    # ------------------------------------------------------------------ reading

    def read(self, digest: str) -> bytes:
        """The whole blob, verified."""
        try:
            data = self.fs.cat_file(self._path(digest))
        except FileNotFoundError:
            raise BlobNotFound(digest) from None
        actual = digest_bytes(data)
        if actual != digest:
            raise BlobCorrupted(digest, actual)
        return data

    def open(self, digest: str) -> BinaryIO:
        """A streaming reader, not verified (call `verify` or use `download` when it matters)."""
        try:
            return self.fs.open(self._path(digest), "rb")
        except FileNotFoundError:
            raise BlobNotFound(digest) from None

    def verify(self, digest: str) -> None:
        with self.open(digest) as stream:
            actual, _ = hash_chunks(read_chunks(stream))
        if actual != digest:
            raise BlobCorrupted(digest, actual)

    def download(self, digest: str, dest: str | Path) -> Path:
        """Copy a blob to a local file, streamed and verified; `dest` appears only if intact."""
        dest = Path(dest)
        dest.parent.mkdir(parents=True, exist_ok=True)
        temporary = dest.with_name(f".{dest.name}.tmp-{uuid.uuid4().hex}")
        try:
            with self.open(digest) as stream, open(temporary, "wb") as out:
                actual = copy_hashed(read_chunks(stream), out)
            if actual != digest:
                raise BlobCorrupted(digest, actual)
            temporary.replace(dest)
        finally:
            temporary.unlink(missing_ok=True)
        return dest

    def exists(self, digest: str) -> bool:
        return self.fs.exists(self._path(digest))

    def size(self, digest: str) -> int:
        try:
            return self.fs.size(self._path(digest))
        except FileNotFoundError:
            raise BlobNotFound(digest) from None

    def modified(self, digest: str) -> datetime:
        try:
            return self.fs.modified(self._path(digest))
        except FileNotFoundError:
            raise BlobNotFound(digest) from None

    def local_path(self, digest: str) -> Path | None:
        """The blob's file on this machine (file:// stores), for Range responses and workers; else None."""
        if not isinstance(self.fs, LocalFileSystem):
            return None
        path = Path(self._path(digest))
        if not path.is_file():
            raise BlobNotFound(digest)
        return path

    def blob_url(self, digest: str) -> str:
        """The blob's fsspec URL, which a worker on any node with access to the store can read."""
        return self.fs.unstrip_protocol(self._path(digest))

    def digests(self) -> Iterator[str]:
        """Every stored digest (temporary files of writes in progress are skipped)."""
        base = f"{self.root}/blobs/sha256"
        if not self.fs.exists(base):
            return
        for path in self.fs.find(base):
            prefix, _, rest = path[len(base) + 1 :].partition("/")
            candidate = format_digest(prefix + rest)
            try:
                parse_digest(candidate)
            except ValueError:
                continue
            yield candidate

    # ------------------------------------------------------------------ deleting

    def delete(self, digest: str) -> None:
        """Remove a blob; deleting one that is absent is not an error (garbage collection may race)."""
        with contextlib.suppress(FileNotFoundError):
            self.fs.rm(self._path(digest))

    def _path(self, digest: str) -> str:
        hex_digest = parse_digest(digest)
        return f"{self.root}/blobs/sha256/{hex_digest[:2]}/{hex_digest[2:]}"
