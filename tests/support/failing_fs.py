"""A local fsspec filesystem (`failing://<absolute path>`) whose writes fail with ENOSPC (a full disk)
while a budget of failures lasts: what an artifact store on a disk that fills up does."""

from __future__ import annotations

import errno
import threading

import fsspec
from fsspec.implementations.local import LocalFileSystem

PROTOCOL = "failing"


class FailingFileSystem(LocalFileSystem):
    protocol = PROTOCOL
    root_marker = "/"
    failures_left = 0  # class-wide: set by the test
    failed = 0
    _lock = threading.Lock()

    @classmethod
    def _strip_protocol(cls, path):
        path = str(path)
        if path.startswith(f"{PROTOCOL}://"):
            path = path[len(PROTOCOL) + 3 :]
        return super()._strip_protocol(path)

    def _open(self, path, mode="rb", *args, **kwargs):
        if "w" in mode or "a" in mode:
            with FailingFileSystem._lock:
                if FailingFileSystem.failures_left > 0:
                    FailingFileSystem.failures_left -= 1
                    FailingFileSystem.failed += 1
                    raise OSError(errno.ENOSPC, "No space left on device (injected)", path)
        return super()._open(path, mode, *args, **kwargs)


def register() -> None:
    fsspec.register_implementation(PROTOCOL, FailingFileSystem, clobber=True)
