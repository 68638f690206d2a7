"""Settings for the whole suite, made before any test module imports torch (Ray's workers and the servers
the tests start inherit them): importing `workers` first makes OpenMP's idle threads wait passively (see
its docstring), and the scenes nodes fetch are cached in a folder of the run's own, removed at its end,
rather than in the machine's `<temp dir>/nbake-scenes`."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

import workers  # noqa: F401
from workers.scene.portability.stored import CACHE_ENV

if CACHE_ENV not in os.environ:
    os.environ[CACHE_ENV] = tempfile.mkdtemp(prefix="nbake-test-scenes-")
    atexit.register(shutil.rmtree, os.environ[CACHE_ENV], ignore_errors=True)
