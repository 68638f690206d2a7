"""Keep freed wavefront arrays in the process heap instead of handing them back to the OS, and hand them
back when a long-lived process decides it is time.

Each bounce allocates and frees a few dozen arrays of about 1 MB ((N, 3) float64 for N = 64k paths).
glibc's malloc serves blocks that large with mmap and trims the heap top when it frees them, so the
next bounce's arrays are fresh pages that the kernel faults and zeroes again (a 128x128, 16 spp render
of cornell_box on one thread: 137k minor faults, 0.25 of 0.58 CPU s in the kernel). Raising the mmap
and trim thresholds (mallopt, glibc only) lets malloc reuse the freed blocks; the cost is that a
process keeps up to `TRIM_THRESHOLD` of freed heap instead of returning it. Process-wide, so set once,
by the first `RayScene` or `PathTracer` (`keep_freed_arrays`).

A server that answers many requests (the inference service) must not keep that much: with the raised
thresholds, each of its request threads got a heap arena whose freed top stayed resident (`malloc_trim`
cannot shrink a thread arena's top; only `free` does, past the trim threshold), 200 MB for 16 threads
answering 36 MB queries one at a time. Such a process calls `return_freed_arrays` when it starts: large
blocks get their own mapping again and go back to the OS when freed, arenas trim their tops beyond a few
MB, and `keep_freed_arrays` leaves that choice alone. It also calls `return_freed_memory` (glibc's
`malloc_trim`: free pages inside every arena) after each stretch of finished work.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 << 20  # blocks above this still get their own mapping (images, scene buffers)
TRIM_THRESHOLD = 512 << 20
SERVER_MMAP_THRESHOLD = 1 << 20  # a server's arrays of 1 MB and more are mapped, and unmapped when freed
SERVER_TRIM_THRESHOLD = 8 << 20

_chosen = False  # the thresholds are set for this process (by either function); the first choice stays


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The C library when it is glibc's (it has mallopt and malloc_trim), else None."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.mallopt, libc.malloc_trim  # noqa: B018 - both exist only in glibc
    except (OSError, AttributeError):
        return None
    return libc


def keep_freed_arrays() -> bool:
    """Raise glibc's thresholds once per process; False where malloc is not glibc's (nothing changes)."""
    return _choose(MMAP_THRESHOLD, TRIM_THRESHOLD)


def return_freed_arrays() -> bool:
    """For a long-lived server, before anything calls `keep_freed_arrays`: low thresholds, so freed
    arrays go back to the OS; False where malloc is not glibc's."""
    return _choose(SERVER_MMAP_THRESHOLD, SERVER_TRIM_THRESHOLD)


def _choose(mmap_threshold: int, trim_threshold: int) -> bool:
    global _chosen
    if _chosen:
        return True
    libc = _glibc()
    if libc is None:
        return False
    _chosen = bool(libc.mallopt(M_MMAP_THRESHOLD, mmap_threshold)) and bool(
        libc.mallopt(M_TRIM_THRESHOLD, trim_threshold)
    )
    return _chosen


def return_freed_memory() -> bool:
    """Give the heap's free pages back to the OS (`malloc_trim(0)`); False where malloc is not glibc's."""
    libc = _glibc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True
