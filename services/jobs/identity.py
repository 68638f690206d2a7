"""What makes two jobs the same work: the idempotency key and the pieces it hashes.

key = sha256(kind, scene content hash, resolved config, seed, code version). The scene content hash
covers the scene description and, for an uploaded asset, the digests of all its files, so the same
scene uploaded twice (or named once as a built-in and once inline) is the same scene.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any


def canonical_json(value: Any) -> bytes:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False).encode()


def sha256_of(value: Any) -> str:
    return "sha256:" + hashlib.sha256(canonical_json(value)).hexdigest()


def scene_hash(scene: dict[str, Any], files: dict[str, str]) -> str:
    """`scene`: the SceneSpec as JSON; `files`: path inside the asset -> digest (empty without an asset)."""
    return sha256_of({"scene": scene, "files": files})


def idempotency_key(kind: str, scene_content: str, config: dict[str, Any], seed: int, code: str) -> str:
    return sha256_of({"kind": kind, "scene": scene_content, "config": config, "seed": seed, "code": code})


@cache
def code_version() -> str:
    """`NBAKE_CODE_VERSION`, else the package version plus the git commit of a source checkout."""
    if override := os.environ.get("NBAKE_CODE_VERSION"):
        return override
    version = metadata.version("neuralbake")
    root = Path(__file__).resolve().parents[2]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short=12", "HEAD"], cwd=root, capture_output=True, text=True, timeout=5
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{version}+g{commit}" if commit else version
