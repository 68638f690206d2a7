"""Numba's `njit` for every compiled kernel of the project, with an on-disk cache that cannot go stale.

Numba keys a cached kernel on the timestamp and size of the one file that defines it, but our kernels
link in helpers from other files (`workers.render.kernels` into the BSDFs, lights and wavefront kernels):
after a change there alone, during development or in an upgrade that replaces only that file, Numba would
load the old machine code. So the cache lives in a folder named by the digest of every kernel source of
the package (each file that uses Numba) and of Numba's version: a change to any of them starts a fresh
cache, compiled once per machine, and older code can never be loaded. Kernel modules import `njit` from
here, so the folder is set before their first decoration.

The folder is `$NBAKE_KERNEL_CACHE` (or `$NUMBA_CACHE_DIR`, or `~/.cache/neuralbake/kernels`) / digest.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba
from numba import njit

PACKAGE = Path(__file__).resolve().parents[1]  # workers/

__all__ = ["kernel_sources_digest", "njit"]


def kernel_sources_digest(package: Path = PACKAGE) -> str:
    """Digest of the Python files of `package` that use Numba (path and content), and of Numba's version."""
    digest = hashlib.sha256(numba.__version__.encode())
    for path in sorted(package.rglob("*.py")):
        text = path.read_bytes()
        if b"numba" in text or b"render.jit" in text:
            digest.update(path.relative_to(package).as_posix().encode() + b"\0" + text + b"\0")
    return digest.hexdigest()[:16]


def _cache_root() -> Path:
    configured = os.environ.get("NBAKE_KERNEL_CACHE") or os.environ.get("NUMBA_CACHE_DIR")
    if configured:
        return Path(configured)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "neuralbake" / "kernels"


numba.config.CACHE_DIR = str(_cache_root() / kernel_sources_digest())
