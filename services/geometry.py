"""Building scene geometry outside the API process: an upload's scene is compiled, and a job's plan made,
in a child process with an address-space ceiling and a deadline. A scene that costs more than it declares
then costs a child (which is replaced), never the server's memory, and a request thread never holds the
server's GIL for seconds of NumPy.
"""

from __future__ import annotations

import multiprocessing
import os
import resource
import threading
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from pebble import ProcessExpired, ProcessPool

from workers.scene.format.errors import SceneError

T = TypeVar("T")
MEMORY_ENV, DEADLINE_ENV = "NBAKE_GEOMETRY_MEMORY_BYTES", "NBAKE_GEOMETRY_DEADLINE_S"
# The default scene limit (8M triangles) compiles in about 4.5 GB; the ceiling leaves room for the
# interpreter, NumPy and trimesh (about 0.4 GB of address space before any scene).
DEFAULT_MEMORY_BYTES = 6 << 30
DEFAULT_DEADLINE_S = 120.0  # an 8M-triangle displaced sphere compiles in about 40 s on this 2-core CPU
WORKERS = 2


def _limit_memory(memory_bytes: int) -> None:
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))


class GeometryProcesses:
    """A small pool of child processes; `run` calls a module-level function in one of them."""

    def __init__(self, memory_bytes: int | None = None, deadline_s: float | None = None):
        self.memory_bytes = memory_bytes or int(os.environ.get(MEMORY_ENV, DEFAULT_MEMORY_BYTES))
        self.deadline_s = deadline_s or float(os.environ.get(DEADLINE_ENV, DEFAULT_DEADLINE_S))
        self._pool: ProcessPool | None = None
        self._lock = threading.Lock()

    def run(self, field: str, fn: Callable[..., T], *args: Any) -> T:
        """`fn(*args)` in a child; its exceptions are raised here, and a child that runs out of memory or
        time is replaced and reported as a SceneError on `field`."""
        future = self._started().schedule(fn, args=args, timeout=self.deadline_s)
        try:
            return future.result()
        except MemoryError:
            raise SceneError(field, self._too_large("ran out of memory")) from None
        except ProcessExpired:
            raise SceneError(field, self._too_large("was killed (out of memory)")) from None
        except FutureTimeout:
            raise SceneError(field, f"building the scene took longer than {self.deadline_s:g} s") from None
        except BrokenProcessPool:
            self.stop()  # children that cannot start: a fresh pool next time, and this request is a 500
            raise

    def _too_large(self, what: str) -> str:
        return f"building the scene {what}: it needs more than {self.memory_bytes >> 20} MiB"

    def _started(self) -> ProcessPool:
        with self._lock:
            if self._pool is None or not self._pool.active:
                self._pool = ProcessPool(
                    max_workers=WORKERS,
                    initializer=_limit_memory,
                    initargs=(self.memory_bytes,),
                    context=multiprocessing.get_context("spawn"),  # the server has threads: never fork it
                )
            return self._pool

    def stop(self) -> None:
        with self._lock:
            if self._pool is not None:
                self._pool.stop()
                self._pool.join()
                self._pool = None
