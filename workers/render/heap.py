"""Keep freed wavefront arrays in the process heap instead of handing them back to the OS.

Each bounce allocates and frees a few dozen arrays of about 1 MB ((N, 3) float64 for N = 64k paths).
glibc's malloc serves blocks that large with mmap and trims the heap top when it frees them, so the
next bounce's arrays are fresh pages that the kernel faults and zeroes again (a 128x128, 16 spp render
of cornell_box on one thread: 137k minor faults, 0.25 of 0.58 CPU s in the kernel). Raising the mmap
and trim thresholds (mallopt, glibc only) lets malloc reuse the freed blocks; the cost is that a
process keeps up to `TRIM_THRESHOLD` of freed heap instead of returning it. Process-wide, so set once,
by the first `RayScene` or `PathTracer` (`keep_freed_arrays`).
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 64 << 20  # blocks above this still get their own mapping (images, scene buffers)
TRIM_THRESHOLD = 512 << 20

_done = False


def keep_freed_arrays() -> bool:
    """Raise glibc's thresholds once per process; False where malloc is not glibc's (nothing changes)."""
    global _done
    if _done:
        return True
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    _done = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
    return _done
