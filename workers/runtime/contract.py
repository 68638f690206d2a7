"""The contract between a model kind and the runtime that runs it: what a kind is given, what it returns,
and how it says that the job (not the kind) must stop.

These types sit below both the kinds (`workers.models`) and the job driver (`workers.driver`), so the
runtime never imports a kind and a kind never imports the driver.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

from pydantic import BaseModel

from workers.runtime.checkpoints import CheckpointStore
from workers.scene.portability.reference import SceneRef

PRESET_NAMES = ("quick", "default", "paper")
ConfigT = TypeVar("ConfigT", bound=BaseModel)


class PlanItem(BaseModel):
    name: str
    choice: str
    reason: str


class Plan(BaseModel):
    """What this scene needs and why, with the estimated cost."""

    items: list[PlanItem]
    estimated_seconds: float
    summary: str


class JobCancelled(Exception):
    """Raised inside a kind's `run` once the job is cancelled; the driver reports a cancelled outcome."""


class InfrastructureFailure(RuntimeError):
    """The cluster, not the job, failed (sampler actors keep dying): the driver marks it retryable."""


@dataclass(frozen=True)
class SamplerSlots:
    """Sampler actors a kind may start (its request, capped to the cluster) and the Ray options that place
    each one in the job's reservation."""

    count: int
    actor_options: dict[str, Any]


def no_reservation(count: int) -> AbstractContextManager[SamplerSlots]:
    """Slots for a job run outside a cluster reservation: actors are placed by Ray's defaults."""
    return nullcontext(SamplerSlots(count=count, actor_options={"num_cpus": 1}))


@dataclass
class JobContext(Generic[ConfigT]):
    """Everything a kind's `run` gets from the driver: inputs, where to write, and how to talk back.

    `config` is the kind's own config model (a kind's run takes `JobContext[ItsConfig]`), resolved and
    validated once, at submission.

    A render reports samples per pixel as steps; a training kind reports optimizer steps and its loss.
    `checkpoints` is the job's own store: a kind resumes from `checkpoints.latest()` when there is one.
    Sampler actors are started inside `with ctx.reserve_samplers(n) as slots:`, which waits until the
    cluster fits them all at once.
    """

    job_id: str
    scene: SceneRef
    config: ConfigT
    seed: int
    output_dir: Path
    checkpoints: CheckpointStore
    reserve_samplers: Callable[[int], AbstractContextManager[SamplerSlots]] = field(
        default=no_reservation, repr=False
    )
    on_progress: Callable[..., None] = field(default=lambda **_: None, repr=False)
    on_log: Callable[[str], None] = field(default=lambda _: None, repr=False)
    cancel_requested: threading.Event = field(default_factory=threading.Event, repr=False)

    def progress(
        self,
        step: int,
        total: int,
        *,
        loss: float | None = None,
        samples_per_s: float | None = None,
        eta_s: float | None = None,
    ) -> None:
        self.on_progress(step=step, total=total, loss=loss, samples_per_s=samples_per_s, eta_s=eta_s)

    def log(self, message: str) -> None:
        self.on_log(message)

    def raise_if_cancelled(self) -> None:
        """Kinds call this between work items, so a cancel takes effect within one item's time."""
        if self.cancel_requested.is_set():
            raise JobCancelled(self.job_id)


@dataclass
class RunOutput:
    """What a finished `run` leaves: artifact files (name -> (local path, media type)), metrics, and
    warnings a person should read (a model worse than the path tracer it replaces, say)."""

    files: dict[str, tuple[str, str]]
    metrics: dict[str, float]
    warnings: list[str] = field(default_factory=list)


def resolve_preset(
    config_model: type[BaseModel], presets: dict[str, dict], preset: str, overrides: dict
) -> BaseModel:
    """The preset's values with `overrides` merged in (nested dicts merge key by key), validated.

    Raises ValueError for an unknown preset and pydantic's ValidationError (naming the field) for bad values.
    """
    if preset not in presets:
        raise ValueError(f"unknown preset {preset!r}; known presets: {', '.join(presets)}")
    # strict: `"256"` or `true` for a count is a mistake to name, not a value to convert
    return config_model.model_validate(merge_nested(presets[preset], overrides or {}), strict=True)


def merge_nested(base: dict, overrides: dict) -> dict:
    """`base` with `overrides` merged in, nested dicts key by key; a dict naming another `type` (another
    member of a discriminated union) replaces the one it overrides."""
    merged = dict(base)
    for key, value in overrides.items():
        old = merged.get(key)
        if (
            isinstance(value, dict)
            and isinstance(old, dict)
            and value.get("type", old.get("type")) == old.get("type")
        ):
            merged[key] = merge_nested(old, value)
        else:
            merged[key] = value
    return merged


@dataclass(frozen=True)
class Example:
    """The smallest job that exercises a kind: a built-in scene and overrides of its `quick` preset. The
    contract tests run it for every registered kind, and the docs show it."""

    scene: str
    overrides: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Kind:
    """A kind declared by name and importable parts, so that registering it loads neither torch nor the
    path tracer: the parts are "module:attribute" strings imported on first use (the server plans in its
    own process; only drivers run).

    A kind that trains names its `method` (a `workers.runtime.pipeline.Method` class), which the driver
    runs on the shared pipeline; a kind that does not (`render`) names a `run` function of its own."""

    name: str
    config_model: type[BaseModel]
    presets: dict[str, dict]
    plan_function: str  # called as function(scene: SceneRef, config) -> Plan
    example: Example
    method: str | None = None  # a Method class, instantiated once per job
    run_function: str | None = None  # called as function(ctx: JobContext) -> RunOutput
    infer_module: str | None = None  # a module exposing INFERENCE, for kinds the inference service serves
    # scene material type -> the function drawing it (`workers.render.aggregate_materials`)
    materials: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if (self.method is None) == (self.run_function is None):
            raise ValueError(f"kind {self.name!r} names either a method or a run function")
        if set(self.presets) != set(PRESET_NAMES):
            raise ValueError(
                f"kind {self.name!r} has presets {sorted(self.presets)}, not {list(PRESET_NAMES)}"
            )
        for (
            preset
        ) in PRESET_NAMES:  # a preset that does not validate fails at registration, not at submission
            self.resolve_config(preset, {})

    def resolve_config(self, preset: str, overrides: dict) -> BaseModel:
        return resolve_preset(self.config_model, self.presets, preset, overrides)

    def stored_config(self, resolved: dict) -> BaseModel:
        """The config a job stored (`resolve_config`'s, as JSON) as the kind's model again, on the driver's
        side of the store. It was checked strictly at submission; this only reads it back, so JSON's lists
        and strings stand for the model's tuples and enums."""
        return self.config_model.model_validate(resolved)

    def plan(self, scene: SceneRef, config: BaseModel) -> Plan:
        return imported(self.plan_function)(scene, config)


def imported(target: str) -> Any:
    """The attribute a "package.module:attribute" string names."""
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)
