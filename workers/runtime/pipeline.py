"""One pipeline for every kind that trains: the kind writes its method, the pipeline does the rest.

As in nerfstudio's split of model, data manager and pipeline, a kind's `Method` supplies its parts: what to
train (`Trainable`: a model, its sample source, its loss and loop settings), how to export the trained
models and what its model renders of the report's view (`Finished`). The pipeline reserves the job's
sampler actors and opens their pool (dead samplers become a retryable `InfrastructureFailure` in
`workers.runtime.samplers`), trains each model with exact resume from its own checkpoint sub-store,
reports progress across all of them and stops on cancel, rounds weights to their stored precision,
measures the model's frame against path tracing of the same view (`workers.runtime.report`), writes the
report, `preview.png` and the reference and the model's frame alone (for a comparison slider), and returns
the `RunOutput`, with a warning when the model is worse than 1-spp path tracing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Protocol, TypeVar

import numpy as np
import torch

from workers.runtime.contract import JobContext, RunOutput, SamplerSlots
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.report import TimedImage, build_report, parameter_bytes
from workers.runtime.samplers import BatchStream, Renders, open_batches, open_renders
from workers.runtime.sources import SourceSpec
from workers.runtime.threads import torch_threads
from workers.runtime.training import Phase, Progress, TrainConfig, TrainResult, train_phases
from workers.runtime.view import PathTracedView
from workers.scene.importers.image_io import write_png

TrainedConfigT = TypeVar("TrainedConfigT", bound=TrainedKindConfig)
PREVIEW = "preview.png"  # the reference, any images the kind adds, and the model's frame, side by side
REFERENCE_PNG, FRAME_PNG = "reference.png", "frame.png"  # the two alone, for a comparison slider


@dataclass
class Trainable:
    """One model to train: its step's phases (one loss and optimizer, or several such as a GAN's
    discriminator and generator, `workers.runtime.training.Phase`) on batches of `source`. `name` names
    its checkpoint sub-store (empty: the job's store itself)."""

    model: torch.nn.Module
    phases: list[Phase]
    source: SourceSpec
    train: TrainConfig
    name: str = ""
    stored_dtype: torch.dtype | None = torch.float16  # the artifact's precision, measured as shipped
    # A trainer that chooses what to render (active exploration): given the renders of `source` (a
    # `RequestSource`) by the job's sampler actors, it returns the batch stream to train on, in place of
    # `source`'s seed-indexed batches.
    driven: Callable[[Renders], BatchStream] | None = None
    # A comparison run rather than a part of the artifact (a baseline at equal training time): given the
    # trainables trained before it, its step count, decided once they have trained; it counts in neither
    # the report's training figures nor its parameter bytes.
    baseline_steps: Callable[[list[Trained]], int] | None = None


@dataclass
class Trained:
    trainable: Trainable
    result: TrainResult

    @property
    def model(self) -> torch.nn.Module:
        return self.trainable.model


@dataclass
class Finished:
    """What a method leaves after export: files, its model's frame of `view`, and its own figures.

    `frame` is rendered at the view's settings, whose spp is the config's `evaluation_spp`."""

    files: dict[str, tuple[str, str]]
    view: PathTracedView
    frame: TimedImage
    method_metrics: dict[str, float] = field(default_factory=dict)
    metrics: dict[str, float] = field(default_factory=dict)  # the job's headline figures beside the report's
    preview: Sequence[np.ndarray] = ()  # images shown between the reference and the model's frame


class Method(Protocol[TrainedConfigT]):
    """What a training kind writes, for its config's type."""

    kind: str  # the kind's registered name, as the report names it

    def trainables(self, ctx: JobContext[TrainedConfigT]) -> list[Trainable]:
        """The models to train, in order (built before any trains: their sources fix the batches)."""
        ...

    def finish(self, ctx: JobContext[TrainedConfigT], trained: list[Trained]) -> Finished:
        """Export the trained models into `ctx.output_dir` and render the report's frame."""
        ...


def run_method(method: Method[TrainedConfigT], ctx: JobContext[TrainedConfigT]) -> RunOutput:
    """Train, export and measure a kind's method as one job (the module docstring lists the steps), with
    the config's `torch_threads` for the job's duration only."""
    if ctx.config.torch_threads is None:
        return _run_method(method, ctx)
    with torch_threads(ctx.config.torch_threads):
        return _run_method(method, ctx)


def _run_method(method: Method[TrainedConfigT], ctx: JobContext[TrainedConfigT]) -> RunOutput:
    trainables = method.trainables(ctx)
    trained = _train_all(ctx, trainables, ctx.config.samplers)
    ctx.raise_if_cancelled()
    finished = method.finish(ctx, trained)
    ctx.raise_if_cancelled()
    ctx.log(
        f"measuring against path tracing at {finished.view.settings.width}x{finished.view.settings.height}"
    )
    shipped = [t for t in trained if t.trainable.baseline_steps is None]
    report = build_report(
        method.kind,
        TrainResult.combined([t.result for t in shipped]),
        sum(parameter_bytes(t.model, t.trainable.stored_dtype) for t in shipped),
        finished.frame,
        finished.view.curve(),
        finished.view.reference(),
        method_metrics=finished.method_metrics,
    )
    files = dict(finished.files)
    files.update(report.write(str(ctx.output_dir)))
    reference = finished.view.reference()
    for name, image in (
        (PREVIEW, np.concatenate([reference, *finished.preview, finished.frame.image], 1)),
        (REFERENCE_PNG, reference),
        (FRAME_PNG, finished.frame.image),
    ):
        write_png(ctx.output_dir / name, image)
        files[name] = (str(ctx.output_dir / name), "image/png")
    for warning in report.warnings():
        ctx.log(f"warning: {warning}")
    metrics = {
        "flip": report.model.error.flip,
        "flip_path_tracing_equal_time": report.path_tracing_equal_time.error.flip,
        **{f"equal_time_ratio_{metric}": ratio for metric, ratio in report.equal_time_ratio.items()},
        "parameter_bytes": float(report.parameter_bytes),
        "worse_than_one_spp": float(report.worse_than_one_spp),
        **finished.metrics,
    }
    return RunOutput(files=files, metrics=metrics, warnings=report.warnings())


def _train_all(ctx: JobContext, trainables: list[Trainable], samplers: int) -> list[Trained]:
    """Each trainable in turn on the job's sampler actors (or in process without any), resuming from its
    checkpoints; progress counts steps across all of them. A baseline's steps are decided when its turn
    comes (`Trainable.baseline_steps`)."""
    total = sum(t.train.steps for t in trainables)
    trained: list[Trained] = []
    if not trainables:
        return trained
    with ctx.reserve_samplers(samplers) as slots:
        ctx.log(f"training {len(trainables)} model(s) on {slots.count or 'no'} sampler actor(s)")
        done = 0
        for trainable in trainables:
            ctx.raise_if_cancelled()
            if trainable.baseline_steps is not None:
                steps = trainable.baseline_steps(trained)
                total += steps - trainable.train.steps
                trainable.train = trainable.train.model_copy(update={"steps": steps})
            store = ctx.checkpoints.sub(trainable.name) if trainable.name else ctx.checkpoints

            def progress(p: Progress, done: int = done, total: int = total) -> None:
                ctx.raise_if_cancelled()
                ctx.progress(done + p.step, total, loss=p.loss, samples_per_s=p.samples_per_s, eta_s=p.eta_s)

            with _open_stream(trainable, slots) as batches:
                result = train_phases(
                    trainable.model, trainable.phases, batches, trainable.train, store, progress
                )
            if trainable.stored_dtype is not None:
                round_to_storage(trainable.model, trainable.stored_dtype)
            trained.append(Trained(trainable, result))
            done += trainable.train.steps
    for t in trained:
        t.model.eval()
    return trained


@contextmanager
def _open_stream(trainable: Trainable, slots: SamplerSlots) -> Iterator[BatchStream]:
    """The trainable's batches: seed-indexed from its source, or driven by its trainer over renders."""
    if trainable.driven is None:
        with open_batches(trainable.source, slots.count, placement=slots.actor_options) as batches:
            yield batches
        return
    with (
        open_renders(trainable.source, slots.count, placement=slots.actor_options) as renders,
        trainable.driven(renders) as batches,
    ):
        yield batches


def round_to_storage(model: torch.nn.Module, dtype: torch.dtype) -> torch.nn.Module:
    """Round the trained parameters to `dtype` and back, so what is measured is what the artifact holds
    (buffers such as row maps or frequencies are rebuilt on load, not stored at that precision)."""
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.copy_(parameter.to(dtype))
    return model
