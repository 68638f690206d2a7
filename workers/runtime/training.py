"""The training loop every model kind runs: batches in, Adam steps, checkpoints, progress, exact resume.

A step runs one or more phases, each a loss descended by its own named Adam with its own parameters,
schedule, clipping and grad scaler: one phase for a kind that fits one network, two alternating ones for
a GAN's discriminator and generator. The learning rate is a pure function of the step (no scheduler
object carrying state), and a checkpoint holds the weights, every optimizer's state and grad scaler, the
RNG states, the next batch index and each phase's latest loss, and the batch stream's own state when it
has any (`ResumableStream`: an active-exploration trainer's chains and patch store); resuming from step k
and running to n therefore repeats the uninterrupted run exactly (bit for bit on CPU).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, Protocol, runtime_checkable

import torch
from pydantic import BaseModel, Field
from torch.optim.optimizer import ParamsT

from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import BatchStream
from workers.runtime.sources import Batch
from workers.scene.format.strict import StrictModel

LossFunction = Callable[[torch.nn.Module, Batch], torch.Tensor]
MAIN_PHASE = "main"  # the one phase of `train`
STREAM_FILE_PREFIX = "stream-"  # the names of a `ResumableStream`'s files in a checkpoint


@runtime_checkable
class ResumableStream(Protocol):
    """A batch stream whose next batches depend on more than its position (a trainer that chooses its
    samples from what it has seen): its state goes into every checkpoint beside the model's."""

    def state_files(self) -> dict[str, bytes]:
        """The stream's state now, as named files (names start with `STREAM_FILE_PREFIX`)."""
        ...

    def restore(self, files: dict[str, bytes]) -> None:
        """Return to the state `state_files` gave (`files` is the whole checkpoint)."""
        ...


class TrainingDiverged(RuntimeError):
    """The loss or a gradient became NaN or infinite; carries the step and the tensor that went bad."""

    def __init__(self, step: int, tensor: str, value: float) -> None:
        super().__init__(
            f"training diverged at step {step}: {tensor} is {value}; "
            "lower the learning rate, enable gradient clipping or check the loss for unguarded divisions"
        )
        self.step = step
        self.tensor = tensor


class Schedule(StrictModel):
    """Learning rate against step: linear warmup, then constant, exponential decay or cosine decay."""

    lr: float = Field(1e-3, gt=0, description="The peak learning rate.")
    kind: Literal["constant", "exponential", "cosine"] = Field(
        "constant", description="The rate's shape after warmup: constant, exponential or cosine decay."
    )
    warmup_steps: int = Field(
        0, ge=0, le=10_000_000, description="Steps of linear warmup from lr / warmup_steps to lr."
    )
    decay_rate: float = Field(
        0.1, gt=0, le=1, description="Exponential decay: the factor reached after `decay_steps`."
    )
    decay_steps: int = Field(
        10_000, ge=1, le=10_000_000, description="Exponential decay: steps to reach `decay_rate`."
    )
    final_lr_fraction: float = Field(
        0.0, ge=0, le=1, description="Cosine decay: the floor at the last step, as a fraction of `lr`."
    )

    def at(self, step: int, total_steps: int) -> float:
        if step < self.warmup_steps:
            return self.lr * (step + 1) / self.warmup_steps
        after_warmup = step - self.warmup_steps
        if self.kind == "exponential":
            return self.lr * self.decay_rate ** (after_warmup / self.decay_steps)
        if self.kind == "cosine":
            progress = min(after_warmup / max(total_steps - self.warmup_steps, 1), 1.0)
            floor = self.final_lr_fraction
            return self.lr * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress)))
        return self.lr


class OptimizerConfig(StrictModel):
    """One Adam's knobs: its learning-rate schedule, moment decays, weight decay and gradient clipping."""

    schedule: Schedule = Field(Schedule(), description="The learning rate against the step.")
    betas: tuple[float, float] = Field(
        (0.9, 0.99), description="Adam's decays of its first and second moment estimates."
    )
    eps: float = Field(1e-15, gt=0, description="Adam's epsilon, added to the second moment's root.")
    weight_decay: float = Field(0.0, ge=0, description="Adam's L2 weight decay.")
    grad_clip_norm: float | None = Field(
        None, gt=0, description="Clip the gradients' global norm to this (null: no clipping)."
    )
    fused: bool = Field(
        False,
        description="PyTorch's fused Adam, one kernel per parameter's update (prt's network: 7.2 -> 0.7 CPU "
        "ms a step); it rounds differently, so off unless a kind measured it.",
    )


class TrainConfig(OptimizerConfig):
    """The loop's knobs; model kinds embed this in their own presets.

    The optimizer fields it inherits configure every phase that `optimizers` does not name: a kind with
    one network sets them directly, a GAN sets `optimizers["generator"]` and `["discriminator"]`.
    """

    steps: int = Field(1000, ge=1, le=10_000_000, description="Optimizer steps of the whole run.")
    optimizers: dict[str, OptimizerConfig] = Field(
        default_factory=dict,
        description="Per-phase optimizers by phase name (a GAN's `generator` and `discriminator`); a phase "
        "not named uses the loop's own settings.",
    )
    mixed_precision: bool = Field(
        True, description="Mixed precision with a grad scaler, on CUDA only; CPU runs stay in float32."
    )
    checkpoint_every: int = Field(
        500, ge=1, le=10_000_000, description="Steps between checkpoints the job resumes from."
    )
    progress_every: int = Field(
        10, ge=1, le=10_000_000, description="Steps between progress reports (loss, rate, ETA)."
    )

    def optimizer(self, phase: str) -> OptimizerConfig:
        """The settings of the named phase's optimizer: its entry in `optimizers`, else the loop's own."""
        if phase in self.optimizers:
            return self.optimizers[phase]
        return OptimizerConfig.model_validate(self.model_dump(include=set(OptimizerConfig.model_fields)))


@dataclass
class Phase:
    """One named optimizer's part of a training step: the loss it descends, the parameters it moves and
    how often it runs (on steps 0, `every`, 2 `every`, ...).

    A GAN is two phases over one model: the discriminator's every step and the generator's every k-th (k
    discriminator updates per generator update). The generator's loss backpropagates through the
    discriminator but moves only the generator: a phase steps its own parameters and then drops every
    gradient its loss left, so the next phase starts from none. `parameters` are tensors or Adam parameter
    groups (default: all of the model's); a group may set `weight_decay` and an `lr_scale` that multiplies
    the scheduled rate, e.g. to treat a hash grid and an MLP differently.
    """

    name: str
    loss: LossFunction
    parameters: ParamsT | None = None
    every: int = 1
    # called with the phase's Adam once it is built, for a sampler that reads its moments (the size of
    # the step a sample's gradient would cause, say); it must not change the optimizer
    on_optimizer: Callable[[torch.optim.Optimizer], None] | None = None

    def __post_init__(self) -> None:
        if not self.name.isidentifier():  # it names the phase's checkpoint files and progress entries
            raise ValueError(f"a phase's name must be an identifier, got {self.name!r}")
        if self.every < 1:
            raise ValueError(f"phase {self.name} runs every `every` steps, at least 1, got {self.every}")
        if self.parameters is not None:
            self.parameters = list(self.parameters)  # a generator such as `module.parameters()` runs dry


class Progress(BaseModel):
    """One progress event, as persisted and streamed to clients."""

    step: int
    total_steps: int
    loss: float  # the sum of `losses`
    losses: dict[str, float]  # each phase's latest loss, by phase name
    lr: float  # the first phase's scheduled rate at the step
    samples_per_s: float
    eta_s: float


@dataclass
class TrainResult:
    """What the report needs from a finished run."""

    steps: int
    final_loss: float
    best_loss: float
    seconds: float
    samples: int

    @property
    def samples_per_s(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else 0.0

    @classmethod
    def combined(cls, results: Sequence[TrainResult]) -> TrainResult:
        """Runs made one after another (e.g. one network per object) as one run: steps, seconds and
        samples add up, the final loss is the last run's and the best loss the lowest (NaN only if
        every run's is). No runs: nothing trained, zero steps, seconds and samples and NaN losses."""
        if not results:
            return cls(steps=0, final_loss=math.nan, best_loss=math.nan, seconds=0.0, samples=0)
        return cls(
            steps=sum(r.steps for r in results),
            final_loss=results[-1].final_loss,
            best_loss=min(
                (r.best_loss for r in results), key=lambda loss: math.inf if math.isnan(loss) else loss
            ),
            seconds=sum(r.seconds for r in results),
            samples=sum(r.samples for r in results),
        )


def select_device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


class _PhaseOptimizer:
    """A phase's Adam with its settings and grad scaler; `update` is one step of the phase."""

    def __init__(
        self, phase: Phase, config: OptimizerConfig, model: torch.nn.Module, device_type: str, amp: bool
    ) -> None:
        self.phase, self.config, self.device_type, self.amp = phase, config, device_type, amp
        self.adam = torch.optim.Adam(
            model.parameters() if phase.parameters is None else phase.parameters,
            lr=config.schedule.lr,
            betas=config.betas,
            eps=config.eps,
            weight_decay=config.weight_decay,
            fused=config.fused or None,  # None, not False: PyTorch picks (foreach on CUDA)
        )
        self.scaler = torch.amp.GradScaler(self.device_type, enabled=amp)
        if phase.on_optimizer is not None:
            phase.on_optimizer(self.adam)
        self.parameters = [p for group in self.adam.param_groups for p in group["params"]]

    def lr(self, step: int, total_steps: int) -> float:
        return self.config.schedule.at(step, total_steps)

    def update(self, model: torch.nn.Module, batch: Batch, step: int, total_steps: int) -> float:
        """One Adam step on the phase's loss, which it returns; raises `TrainingDiverged` on a non-finite
        loss or gradient. Leaves no gradient on any of the model's parameters."""
        lr = self.lr(step, total_steps)
        for group in self.adam.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        with torch.autocast(self.device_type, enabled=self.amp):
            loss = self.phase.loss(model, batch)
        self.scaler.scale(loss).backward()
        self.scaler.unscale_(self.adam)
        grad_norm = torch.nn.utils.get_total_norm([p.grad for p in self.parameters if p.grad is not None])
        loss_value, grad_norm_value = torch.stack([loss.detach().float(), grad_norm.float()]).tolist()
        if not math.isfinite(loss_value):
            raise TrainingDiverged(step, f"{self.phase.name} loss", loss_value)
        if not self.amp and not math.isfinite(grad_norm_value):  # with AMP the scaler skips such steps itself
            raise TrainingDiverged(step, *self._first_nonfinite_gradient(model))
        if self.config.grad_clip_norm is not None:
            torch.nn.utils.clip_grads_with_norm_(self.parameters, self.config.grad_clip_norm, grad_norm)
        self.scaler.step(self.adam)
        self.scaler.update()
        model.zero_grad(set_to_none=True)  # also what the loss left on other phases' parameters
        return loss_value

    def _first_nonfinite_gradient(self, model: torch.nn.Module) -> tuple[str, float]:
        own = {id(p) for p in self.parameters}
        for name, parameter in model.named_parameters():
            grad = parameter.grad
            if id(parameter) in own and grad is not None and not torch.isfinite(grad).all():
                return f"gradient of {name}", float(grad[~torch.isfinite(grad)][0])
        return "gradient norm", math.nan


def _check_phase_names(phases: Sequence[Phase], config: TrainConfig) -> None:
    names = [phase.name for phase in phases]
    if not names or len(set(names)) < len(names):
        raise ValueError(f"training needs at least one phase and distinct phase names, got {names}")
    if unknown := sorted(set(config.optimizers) - set(names)):
        raise ValueError(f"config.optimizers names {unknown}, which no phase has; the phases are {names}")


class _ProgressMeter:
    """Turns steps into progress events: rates and ETA over the window since the previous event."""

    def __init__(self, total_steps: int) -> None:
        self.total_steps = total_steps
        self.samples = 0
        self._restart_window()

    def _restart_window(self) -> None:
        self.window_start, self.window_samples, self.window_steps = time.perf_counter(), 0, 0

    def count(self, batch: Batch) -> None:
        size = len(next(iter(batch.values())))
        self.samples += size
        self.window_samples += size
        self.window_steps += 1

    def event(self, step: int, losses: dict[str, float], lr: float) -> Progress:
        window = max(time.perf_counter() - self.window_start, 1e-9)
        progress = Progress(
            step=step,
            total_steps=self.total_steps,
            loss=sum(losses.values()),
            losses=dict(losses),
            lr=lr,
            samples_per_s=self.window_samples / window,
            eta_s=(self.total_steps - step) * window / self.window_steps,
        )
        self._restart_window()
        return progress


def _stream_files(stream: ResumableStream) -> dict[str, bytes]:
    files = stream.state_files()
    if stray := sorted(name for name in files if not name.startswith(STREAM_FILE_PREFIX)):
        raise ValueError(f"a stream's checkpoint files are named {STREAM_FILE_PREFIX}*, got {stray}")
    return files


def train(
    model: torch.nn.Module,
    loss_fn: LossFunction,
    batches: BatchStream,
    config: TrainConfig,
    checkpoints: CheckpointStore | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    param_groups: list[dict[str, Any]] | None = None,
) -> TrainResult:
    """Train `model` on one loss with one Adam: `train_phases` with the single phase `main`.

    `loss_fn(model, batch)` returns a scalar loss; `param_groups` are the phase's parameters (see `Phase`).
    """
    phase = Phase(MAIN_PHASE, loss_fn, param_groups)
    return train_phases(model, [phase], batches, config, checkpoints, on_progress)


def train_phases(
    model: torch.nn.Module,
    phases: Sequence[Phase],
    batches: BatchStream,
    config: TrainConfig,
    checkpoints: CheckpointStore | None = None,
    on_progress: Callable[[Progress], None] | None = None,
) -> TrainResult:
    """Train `model` on `batches` for `config.steps` steps, resuming from the latest checkpoint if any.

    Each step runs the phases due at it, in order, on the same batch (already on the model's device);
    each phase's optimizer is configured by `config.optimizer(phase.name)`. The step's loss (progress,
    best and final loss) is the sum of every phase's latest loss, so it is the loss itself for one phase.
    """
    _check_phase_names(phases, config)
    device = select_device()
    model.to(device)
    amp = config.mixed_precision and device.type == "cuda"
    optimizers = [
        _PhaseOptimizer(phase, config.optimizer(phase.name), model, device.type, amp) for phase in phases
    ]
    adams = {o.phase.name: o.adam for o in optimizers}
    scalers = {o.phase.name: o.scaler for o in optimizers}
    loop = training_state.LoopState()
    resumable = isinstance(batches, ResumableStream)
    if checkpoints is not None and (latest := checkpoints.latest()) is not None:
        files = checkpoints.load(latest)
        loop = training_state.decode(files, model, adams, scalers)
        loop.restore_rng()
        if resumable:
            batches.restore(files)
    batches.seek(loop.batch_position)
    step, best_loss, losses = loop.step, loop.best_loss, dict(loop.losses)
    meter = _ProgressMeter(config.steps)
    started = time.perf_counter()
    loss_value = math.nan
    while step < config.steps:
        batch = {k: v.to(device, non_blocking=True) for k, v in next(batches).items()}
        for optimizer in optimizers:
            if step % optimizer.phase.every == 0:
                losses[optimizer.phase.name] = optimizer.update(model, batch, step, config.steps)
        loss_value = sum(losses.values())

        step += 1
        best_loss = loss_value if best_loss is None else min(best_loss, loss_value)
        meter.count(batch)
        if checkpoints is not None and (step % config.checkpoint_every == 0 or step == config.steps):
            state = training_state.LoopState.capture(step, batches.position, best_loss, losses)
            files = training_state.encode(model, adams, scalers, state)
            checkpoints.save(step, files | (_stream_files(batches) if resumable else {}))
        if on_progress is not None and (step % config.progress_every == 0 or step == config.steps):
            on_progress(meter.event(step, losses, optimizers[0].lr(step - 1, config.steps)))

    return TrainResult(
        steps=step,
        final_loss=loss_value,
        best_loss=math.nan if best_loss is None else best_loss,
        seconds=time.perf_counter() - started,
        samples=meter.samples,
    )
