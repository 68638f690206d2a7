"""Benchmarks: run with `make bench`; never asserted on time, always reported as ratios to a peer."""

import workers  # noqa: F401  (before any bench imports torch: OpenMP's passive wait, see its docstring)
