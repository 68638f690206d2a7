"""The training loop every model kind runs: batches in, Adam steps, checkpoints, progress, exact resume.

The learning rate is a pure function of the step (no scheduler object carrying state), and a checkpoint
holds the weights, Adam's state, the grad scaler, the RNG states and the next batch index; resuming from
step k and running to n therefore repeats the uninterrupted run exactly (bit for bit on CPU).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import torch
from pydantic import BaseModel, Field

from workers.runtime import training_state
from workers.runtime.checkpoints import CheckpointStore
from workers.runtime.samplers import BatchStream
from workers.runtime.sources import Batch

LossFunction = Callable[[torch.nn.Module, Batch], torch.Tensor]


class TrainingDiverged(RuntimeError):
    """The loss or a gradient became NaN or infinite; carries the step and the tensor that went bad."""

    def __init__(self, step: int, tensor: str, value: float) -> None:
        super().__init__(
            f"training diverged at step {step}: {tensor} is {value}; "
            "lower the learning rate, enable gradient clipping or check the loss for unguarded divisions"
        )
        self.step = step
        self.tensor = tensor


class Schedule(BaseModel):
    """Learning rate against step: linear warmup, then constant, exponential decay or cosine decay."""

    lr: float = Field(1e-3, gt=0)
    kind: Literal["constant", "exponential", "cosine"] = "constant"
    warmup_steps: int = Field(0, ge=0)
    decay_rate: float = Field(0.1, gt=0, le=1)  # exponential: factor reached after `decay_steps`
    decay_steps: int = Field(10_000, ge=1)
    final_lr_fraction: float = Field(0.0, ge=0, le=1)  # cosine: the floor, as a fraction of `lr`

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


class TrainConfig(BaseModel):
    """The loop's knobs; model kinds embed this in their own presets."""

    steps: int = Field(1000, ge=1)
    schedule: Schedule = Schedule()
    betas: tuple[float, float] = (0.9, 0.99)
    eps: float = Field(1e-15, gt=0)
    weight_decay: float = Field(0.0, ge=0)
    grad_clip_norm: float | None = Field(None, gt=0)
    mixed_precision: bool = True  # honoured on CUDA only; CPU runs stay in float32
    checkpoint_every: int = Field(500, ge=1)
    progress_every: int = Field(10, ge=1)


class Progress(BaseModel):
    """One progress event, as persisted and streamed to clients."""

    step: int
    total_steps: int
    loss: float
    lr: float
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


def _first_nonfinite_gradient(model: torch.nn.Module) -> tuple[str, float]:
    for name, parameter in model.named_parameters():
        if parameter.grad is not None and not torch.isfinite(parameter.grad).all():
            bad = parameter.grad[~torch.isfinite(parameter.grad)]
            return f"gradient of {name}", float(bad[0])
    return "gradient norm", math.nan


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

    def event(self, step: int, loss: float, lr: float) -> Progress:
        window = max(time.perf_counter() - self.window_start, 1e-9)
        progress = Progress(
            step=step,
            total_steps=self.total_steps,
            loss=loss,
            lr=lr,
            samples_per_s=self.window_samples / window,
            eta_s=(self.total_steps - step) * window / self.window_steps,
        )
        self._restart_window()
        return progress


def train(
    model: torch.nn.Module,
    loss_fn: LossFunction,
    batches: BatchStream,
    config: TrainConfig,
    checkpoints: CheckpointStore | None = None,
    on_progress: Callable[[Progress], None] | None = None,
    param_groups: list[dict[str, Any]] | None = None,
) -> TrainResult:
    """Train `model` on `batches` for `config.steps` steps, resuming from the latest checkpoint if any.

    `loss_fn(model, batch)` returns a scalar loss; the batch is already on the model's device.
    `param_groups` (Adam's, default one group of all parameters) may set `weight_decay` and an
    `lr_scale` that multiplies the scheduled rate, e.g. to treat a hash grid and an MLP differently.
    """
    device = select_device()
    model.to(device)
    amp = config.mixed_precision and device.type == "cuda"
    optimizer = torch.optim.Adam(
        param_groups or model.parameters(),
        lr=config.schedule.lr,
        betas=config.betas,
        eps=config.eps,
        weight_decay=config.weight_decay,
    )
    scaler = torch.amp.GradScaler(device.type, enabled=amp)
    loop = training_state.LoopState()
    if checkpoints is not None and (latest := checkpoints.latest()) is not None:
        loop = training_state.decode(checkpoints.load(latest), model, optimizer, scaler)
        loop.restore_rng()
    batches.seek(loop.batch_position)
    step, best_loss = loop.step, loop.best_loss
    parameters = [p for group in optimizer.param_groups for p in group["params"]]
    meter = _ProgressMeter(config.steps)
    started = time.perf_counter()
    loss_value = math.nan
    while step < config.steps:
        batch = {k: v.to(device, non_blocking=True) for k, v in next(batches).items()}
        lr = config.schedule.at(step, config.steps)
        for group in optimizer.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        with torch.autocast(device.type, enabled=amp):
            loss = loss_fn(model, batch)
        scaler.scale(loss).backward()
        scaler.unscale_(optimizer)
        grad_norm = torch.nn.utils.get_total_norm([p.grad for p in parameters if p.grad is not None])
        loss_value, grad_norm_value = torch.stack([loss.detach().float(), grad_norm.float()]).tolist()
        if not math.isfinite(loss_value):
            raise TrainingDiverged(step, "loss", loss_value)
        if not amp and not math.isfinite(grad_norm_value):  # with AMP the scaler skips such steps itself
            raise TrainingDiverged(step, *_first_nonfinite_gradient(model))
        if config.grad_clip_norm is not None:
            torch.nn.utils.clip_grads_with_norm_(parameters, config.grad_clip_norm, grad_norm)
        scaler.step(optimizer)
        scaler.update()
        optimizer.zero_grad(set_to_none=True)

        step += 1
        best_loss = loss_value if best_loss is None else min(best_loss, loss_value)
        meter.count(batch)
        if checkpoints is not None and (step % config.checkpoint_every == 0 or step == config.steps):
            state = training_state.LoopState.capture(step, batches.position, best_loss)
            checkpoints.save(step, training_state.encode(model, optimizer, scaler, state))
        if on_progress is not None and (step % config.progress_every == 0 or step == config.steps):
            on_progress(meter.event(step, loss_value, lr))

    return TrainResult(
        steps=step,
        final_loss=loss_value,
        best_loss=math.nan if best_loss is None else best_loss,
        seconds=time.perf_counter() - started,
        samples=meter.samples,
    )
