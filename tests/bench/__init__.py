"""Benchmarks: run with `make bench`; never asserted on time, always reported as ratios to a peer."""
