"""Timing and reporting shared by every benchmark module."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field


def median_seconds(
    fn: Callable[[], object],
    repeats: int = 5,
    warmup: int = 1,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """Median time of `fn` over `repeats` runs after `warmup` untimed runs: wall time, or with
    `clock=time.process_time` the CPU time of all the process's threads (which other processes on a
    shared machine inflate much less than wall time)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return statistics.median(times)


@dataclass
class BenchSection:
    """One table in the report: rows of named figures, plus ratios against a peer from the same run."""

    title: str
    rows: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def add(self, **row) -> None:
        self.rows.append(row)

    def table(self) -> str:
        if not self.rows:
            return f"## {self.title}\n(no rows)\n"
        keys = list(dict.fromkeys(k for r in self.rows for k in r))
        fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
        widths = {k: max(len(k), *(len(fmt(r.get(k, ""))) for r in self.rows)) for k in keys}
        lines = [f"## {self.title}", "  ".join(k.ljust(widths[k]) for k in keys)]
        lines += ["  ".join(fmt(r.get(k, "")).ljust(widths[k]) for k in keys) for r in self.rows]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines) + "\n"
