"""Settings for the whole suite, made before any test module imports torch (Ray's workers inherit them)."""

from __future__ import annotations

import os

# OpenMP's default active wait spins each idle thread of torch's pool at every parallel region. When the
# 2-core machine runs anything else, a spinning thread holds the core its partner needs, and a region
# waits for a time slice: with one other busy process, a quick-preset lod training step took 0.71 s on
# two threads with active waiting, 0.012 s with passive waiting and 0.020 s on one thread.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
