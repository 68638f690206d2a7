"""Running one job of any kind in this process through the driver's `run_job` (no Ray actor, no server)."""

from __future__ import annotations

import threading
from pathlib import Path

from workers.driver.jobs import JobEvent, JobOutcome, JobSpec, run_job
from workers.models.registry import get_kind
from workers.scene.spec import SceneSpec


def run_kind_job(
    kind: str,
    scene: SceneSpec,
    folder: Path,
    overrides: dict | None = None,
    *,
    preset: str = "quick",
    seed: int = 0,
    events: list[JobEvent] | None = None,
) -> tuple[JobSpec, JobOutcome]:
    """A `kind` job of `preset` + `overrides` on `scene`, checkpoints in folder/checkpoints and the artifact's
    files in folder/out; its events are appended to `events`."""
    config = get_kind(kind).resolve_config(preset, overrides or {})
    spec = JobSpec(
        job_id=f"{kind}-{seed}",
        kind=kind,
        scene=scene.model_dump(mode="json"),
        config=config.model_dump(mode="json"),
        seed=seed,
        checkpoint_dir=str(folder / "checkpoints"),
        output_dir=str(folder / "out"),
    )
    sink = events.append if events is not None else (lambda event: None)
    return spec, run_job(spec, sink, threading.Event())
