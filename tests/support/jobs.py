"""Running one job of any kind in this process through the driver's `run_job` (no Ray actor, no server)."""

from __future__ import annotations

import threading
from pathlib import Path

import safetensors.torch

from workers.driver.jobs import JobEvent, JobOutcome, JobSpec, run_job
from workers.models.registry import get_kind
from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.contract import JobContext, imported
from workers.runtime.pipeline import Trainable, round_to_storage
from workers.scene.format.spec import SceneSpec
from workers.scene.portability.reference import SceneRef


def run_kind_job(
    kind: str,
    scene: SceneSpec,
    folder: Path,
    overrides: dict | None = None,
    *,
    preset: str = "quick",
    seed: int = 0,
    events: list[JobEvent] | None = None,
    cancel_after_step: int | None = None,
    scene_dir: Path | None = None,
) -> tuple[JobSpec, JobOutcome]:
    """A `kind` job of `preset` + `overrides` on `scene` (its files in `scene_dir`), checkpoints in
    folder/checkpoints and the artifact's files in folder/out; its events are appended to `events`. With
    `cancel_after_step`, a user cancels the job when it reports progress at or past that step (it stops at
    its next progress report)."""
    config = get_kind(kind).resolve_config(preset, overrides or {})
    spec = JobSpec(
        job_id=f"{kind}-{seed}",
        kind=kind,
        scene=scene.model_dump(mode="json"),
        scene_dir=None if scene_dir is None else str(scene_dir),
        config=config.model_dump(mode="json"),
        seed=seed,
        checkpoint_dir=str(folder / "checkpoints"),
        output_dir=str(folder / "out"),
    )
    cancel = threading.Event()

    def sink(event: JobEvent) -> None:
        if events is not None:
            events.append(event)
        if cancel_after_step is not None and event.type == "progress" and event.step >= cancel_after_step:
            cancel.set()

    return spec, run_job(spec, sink, cancel)


def trained_models(spec: JobSpec) -> list[Trainable]:
    """The job's trainables as its kind builds them, holding the weights of their last checkpoints rounded
    to their stored precision, as the pipeline holds them when the method exports: what the artifact was
    written from."""
    kind = get_kind(spec.kind)
    ctx = JobContext(
        job_id=spec.job_id,
        scene=SceneRef.from_json(spec.scene, spec.scene_dir),
        config=kind.stored_config(spec.config),
        seed=spec.seed,
        output_dir=Path(spec.output_dir),
        checkpoints=CheckpointStore(spec.checkpoint_dir),
    )
    trainables = imported(kind.method)().trainables(ctx)
    for trainable in trainables:
        store = ctx.checkpoints.sub(trainable.name) if trainable.name else ctx.checkpoints
        files = store.load(store.latest())
        trainable.model.load_state_dict(safetensors.torch.load(files[training_state.MODEL_FILE]))
        if trainable.stored_dtype is not None:
            round_to_storage(trainable.model, trainable.stored_dtype)
        trainable.model.eval()
    return trainables


def progress_steps(events: list[JobEvent]) -> list[int]:
    return [e.step for e in events if e.type == "progress"]


def assert_resumes_to_the_uninterrupted_weights(
    run, uninterrupted: Path, folder: Path, train, weights: list[str]
):
    """A job cancelled just past its first checkpoint and run again in `folder` resumes there (not from
    step 0) and ends with the same bytes in `weights` (paths under the job folder; "{final}" stands for the
    last checkpoint's model file) as the uninterrupted job in `uninterrupted`. `run(folder, **options)`
    returns an object with `outcome` and `events`."""
    every = train.checkpoint_every
    stopped = run(folder, cancel_after_step=every + 1)
    assert stopped.outcome.state == "cancelled"
    assert every < progress_steps(stopped.events)[-1] < train.steps
    resumed = run(folder)
    assert resumed.outcome.state == "succeeded", resumed.outcome.error
    assert progress_steps(resumed.events)[0] == every + train.progress_every  # not the first steps again
    final = f"step-{train.steps:09d}/{training_state.MODEL_FILE}"
    for name in (w.format(final=final) for w in weights):
        assert (folder / name).read_bytes() == (uninterrupted / name).read_bytes(), name
