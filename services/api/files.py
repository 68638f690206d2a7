"""Serving a stored blob over HTTP: strong ETag (its digest), conditional GET, single byte ranges.

A blob is verified against its digest the first time this process serves it; content addressing makes
that check valid for good.
"""

from __future__ import annotations

import re
import threading
from collections.abc import Iterator

from fastapi import Request
from fastapi.responses import Response, StreamingResponse

from services.artifacts.manifest import FileEntry
from services.artifacts.store import BlobStore

CHUNK = 1 << 16
# A blob never changes, but it is one tenant's: a browser may keep it, a shared cache must not.
PRIVATE_IMMUTABLE = "private, max-age=31536000, immutable"
_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")
_verified: set[str] = set()
_verified_lock = threading.Lock()


def blob_response(request: Request, blobs: BlobStore, entry: FileEntry) -> Response:
    etag = f'"{entry.digest}"'
    headers = {"ETag": etag, "Accept-Ranges": "bytes", "Cache-Control": PRIVATE_IMMUTABLE}
    if etag in _listed(request.headers.get("if-none-match")) or request.headers.get("if-none-match") == "*":
        return Response(status_code=304, headers=headers)
    _verify_once(blobs, entry.digest)
    window = _range(request, etag, entry.size)
    if window == "unsatisfiable":
        return Response(status_code=416, headers=headers | {"Content-Range": f"bytes */{entry.size}"})
    start, end = window or (0, entry.size - 1)
    headers["Content-Length"] = str(max(end - start + 1, 0))
    status = 200
    if window is not None:
        status = 206
        headers["Content-Range"] = f"bytes {start}-{end}/{entry.size}"
    return StreamingResponse(
        _chunks(blobs, entry.digest, start, end + 1),
        status_code=status,
        media_type=entry.media_type,
        headers=headers,
    )


def _listed(header: str | None) -> list[str]:
    return [tag.strip().removeprefix("W/") for tag in header.split(",")] if header else []


def _range(request: Request, etag: str, size: int):
    """(start, end) inclusive, None for the whole file, or "unsatisfiable". Multiple ranges: whole file."""
    header = request.headers.get("range")
    if_range = request.headers.get("if-range")
    if header is None or (if_range is not None and if_range != etag):
        return None
    match = _RANGE.match(header.strip())
    if match is None or match.groups() == ("", ""):
        return None  # a syntax we do not serve (e.g. several ranges): RFC 9110 allows the full response
    first, last = match.groups()
    if first == "":
        length = int(last)
        if length == 0 or size == 0:
            return "unsatisfiable"
        return max(size - length, 0), size - 1
    start = int(first)
    end = min(int(last), size - 1) if last else size - 1
    if start >= size or (last and int(last) < start):
        return "unsatisfiable"
    return start, end


def _verify_once(blobs: BlobStore, digest: str) -> None:
    with _verified_lock:
        if digest in _verified:
            return
    blobs.verify(digest)
    with _verified_lock:
        _verified.add(digest)


def _chunks(blobs: BlobStore, digest: str, start: int, stop: int) -> Iterator[bytes]:
    with blobs.open(digest) as stream:
        stream.seek(start)
        remaining = stop - start
        while remaining > 0:
            chunk = stream.read(min(CHUNK, remaining))
            if not chunk:
                break
            remaining -= len(chunk)
            yield chunk
