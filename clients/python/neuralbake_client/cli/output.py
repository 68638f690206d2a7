"""What the job commands print. On a terminal: progress bars (step, loss, samples/s, ETA) and short
summaries on stderr/stdout. Anywhere else, or with `--json`: one JSON object per line on stdout and no
escape codes, so a pipeline can parse every line.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

if TYPE_CHECKING:
    from neuralbake_client.models import Job, JobEvent


class Output:
    def __init__(self, json_lines: bool):
        self.console = Console(stderr=True)
        self.json = json_lines or not sys.stdout.isatty()

    def line(self, event: str, **fields: Any) -> None:
        """One JSON line: `{"event": ..., ...}` (JSON mode only)."""
        print(json.dumps({"event": event, **fields}, default=str), flush=True)

    def job(self, job: Job, event: str = "job", warning: str | None = None) -> None:
        """The job; `warning` is what its artifact was flagged with (a model worse than path tracing). A
        submission's line says whether it got an existing job back (`reused`)."""
        if self.json:
            extra = ({"warning": warning} if warning else {}) | (
                {"reused": job.reused} if event == "submitted" else {}
            )
            self.line(event, job=job.model_dump(mode="json"), **extra)
            return
        print(summary(job))
        if warning:
            self.console.print(f"[bold yellow]warning:[/bold yellow] {warning}")

    @contextmanager
    def following(self, job: Job) -> Iterator[Callable[[JobEvent], None]]:
        """A callback for each event of `job`: a JSON line, or a progress bar and log lines on stderr."""
        if self.json:
            yield lambda e: self.line(
                e.type, job_id=e.job_id, seq=e.seq, time=e.time.isoformat(), data=e.data
            )
            return
        columns = (
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TextColumn("{task.fields[rate]}"),
            TextColumn("eta"),
            TimeRemainingColumn(),
        )
        with Progress(*columns, console=self.console) as bar:
            task = bar.add_task(f"{job.id} {job.state}", total=None, rate="")

            def update(event: JobEvent) -> None:
                if (p := event.progress) is not None:
                    loss = f"loss {p.loss:.4g}  " if p.loss is not None else ""
                    rate = f"{loss}{p.samples_per_s or 0:,.0f} samples/s"
                    bar.update(task, completed=p.step, total=p.total, rate=rate)
                elif event.state is not None:
                    bar.update(task, description=f"{event.job_id} {event.state}")
                elif event.type == "resume":  # progress going back is a restart from a checkpoint
                    step, attempt = event.data.get("to_step"), event.data.get("attempt")
                    bar.console.print(
                        f"[dim]resumed from the checkpoint at step {step} (attempt {attempt})[/dim]"
                    )
                elif event.type == "log":
                    message = event.data.get("message", "")
                    style = "bold yellow" if message.startswith("warning:") else "dim"
                    bar.console.print(f"[{style}]{message}[/{style}]", highlight=False)

            yield update


def summary(job: Job) -> str:
    scene = job.scene.get("name") or job.scene.get("asset_id") or next(iter(job.scene.values()), "")
    text = f"{job.id}  {job.state:<9}  {job.kind}  {scene}  preset={job.preset}"
    if job.reused:
        text += "  (reused: identical work was already there)"
    if job.progress and job.progress.get("total"):
        text += f"  step {job.progress.get('step')}/{job.progress['total']}"
    if job.error:
        text += f"\n  error: {job.error}"
    if job.artifact_id:
        text += f"\n  artifact: {job.artifact_id}"
    return text
