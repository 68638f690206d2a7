"""Content addresses: `sha256:<64 hex>` strings, validated because they arrive in URLs.

Ids of manifests and assets are digests of canonical JSON (sorted keys, no whitespace), so
the same content always gets the same id, whoever writes it.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

ALGORITHM = "sha256"
_DIGEST = re.compile(r"sha256:[0-9a-f]{64}")


def parse_digest(digest: object) -> str:
    """The 64 hex characters of a valid digest; anything else (case, length, prefix) is a ValueError."""
    if not isinstance(digest, str) or _DIGEST.fullmatch(digest) is None:
        shown = repr(digest)[:80]
        raise ValueError(f"not a digest: {shown}; expected 'sha256:' followed by 64 lowercase hex digits")
    return digest[len(ALGORITHM) + 1 :]


def format_digest(hex_digest: str) -> str:
    return f"{ALGORITHM}:{hex_digest}"


def digest_bytes(data: bytes) -> str:
    return format_digest(hashlib.sha256(data).hexdigest())


def canonical_json(data: Any) -> bytes:
    """The one byte string hashed for an id: sorted keys, no whitespace, no NaN."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return text.encode()


def digest_json(data: Any) -> str:
    return digest_bytes(canonical_json(data))


def known_digest(value: str, not_found: type[LookupError]) -> str:
    """An id that is not even a digest names nothing: `not_found` (a 404) like any unknown id."""
    try:
        parse_digest(value)
    except ValueError:
        raise not_found(value) from None
    return value
