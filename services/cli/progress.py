"""Render progress for people and for machines.

On a terminal a rich progress bar (samples, rays/s, ETA) redraws in place on stderr. Anywhere
else (CI logs, pipes) redrawing makes noise, so each pass prints one plain line on stderr, or,
with `--json`, one JSON object on stdout that a pipeline can parse alongside the final result.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from workers.render.render import RenderProgress

ProgressCallback = Callable[[RenderProgress], None]


def rays_per_second(rays: int, seconds: float) -> float:
    return rays / seconds if seconds > 0 else 0.0


def eta_seconds(p: RenderProgress) -> float:
    """Remaining time if the remaining samples go as fast as the finished ones."""
    return p.elapsed * (p.samples_total - p.samples_done) / max(p.samples_done, 1)


def progress_event(p: RenderProgress) -> dict:
    return {
        "event": "progress",
        "samples_done": p.samples_done,
        "samples_total": p.samples_total,
        "elapsed": round(p.elapsed, 4),
        "rays_traced": p.rays_traced,
        "rays_per_second": round(rays_per_second(p.rays_traced, p.elapsed)),
        "eta": round(eta_seconds(p), 4),
    }


def print_json(event: dict) -> None:
    print(json.dumps(event), flush=True)


def _plain_line(label: str, p: RenderProgress) -> str:
    mrays = rays_per_second(p.rays_traced, p.elapsed) / 1e6
    return (
        f"{label}: {p.samples_done}/{p.samples_total} spp ({100 * p.fraction:.0f}%), "
        f"{mrays:.2f} Mrays/s, elapsed {p.elapsed:.1f} s, eta {eta_seconds(p):.1f} s"
    )


@contextmanager
def render_progress(label: str, total: int, json_lines: bool, console: Console) -> Iterator[ProgressCallback]:
    """A callback for `render(progress=...)`, in the form that suits where the output goes."""
    if json_lines:
        yield lambda p: print_json(progress_event(p))
    elif not console.is_terminal:
        yield lambda p: print(_plain_line(label, p), file=sys.stderr, flush=True)
    else:
        columns = (
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total} spp"),
            TextColumn("{task.fields[rate]}"),
            TimeElapsedColumn(),
            TextColumn("eta"),
            TimeRemainingColumn(),
        )
        with Progress(*columns, console=console, transient=False) as bar:
            task = bar.add_task(label, total=total, rate="")

            def update(p: RenderProgress) -> None:
                rate = f"{rays_per_second(p.rays_traced, p.elapsed) / 1e6:.2f} Mrays/s"
                bar.update(task, completed=p.samples_done, rate=rate)

            yield update
