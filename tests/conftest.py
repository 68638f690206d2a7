"""Settings for the whole suite, made before any test module imports torch (Ray's workers inherit them):
importing `workers` first makes OpenMP's idle threads wait passively (see its docstring)."""

from __future__ import annotations

import workers  # noqa: F401
