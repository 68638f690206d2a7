"""The one place that knows every model kind: the job server, the driver and the inference service look
kinds up here by name, so adding a kind is one line in `KIND_MODULES` and no `if kind == ...` elsewhere.

Kinds are imported on first lookup, not when this module is imported: the server validates configs
without loading the path tracer or torch until a kind is actually asked for.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from pydantic import BaseModel

from workers.runtime.checkpoints import CheckpointStore
from workers.scene.spec import SceneSpec

if TYPE_CHECKING:
    import numpy as np

# One line per kind: a module exposing `KIND`, an object satisfying `ModelKind`.
KIND_MODULES = ("workers.models.render", "workers.models.lsnif", "workers.models.lod")
PRESET_NAMES = ("quick", "default", "paper")


class PlanItem(BaseModel):
    name: str
    choice: str
    reason: str


class Plan(BaseModel):
    """What this scene needs and why, with the estimated cost."""

    items: list[PlanItem]
    estimated_seconds: float
    summary: str


class Resources(BaseModel):
    """What a job of this config asks the cluster for (its sampler actors and the driver together)."""

    num_cpus: float = 1
    num_gpus: float = 0


class UnknownKind(KeyError):
    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.name = name

    def __str__(self) -> str:
        return f"unknown model kind {self.name!r}; known kinds: {', '.join(kind_names())}"


class JobCancelled(Exception):
    """Raised inside a kind's `run` once the job is cancelled; the driver reports a cancelled outcome."""


class InfrastructureFailure(RuntimeError):
    """Raised by a kind when the cluster, not the job, failed (workers keep dying): a retry may succeed."""


@dataclass(frozen=True)
class SamplerSlots:
    """Sampler actors a kind may start (its request, capped to the cluster) and the Ray options that place
    each one in the job's reservation."""

    count: int
    actor_options: dict[str, Any]


@dataclass
class JobContext:
    """Everything a kind's `run` gets from the driver: inputs, where to write, and how to talk back.

    A render reports samples per pixel as steps; a training kind reports optimizer steps and its loss.
    `checkpoints` is the job's own store: a kind resumes from `checkpoints.latest()` when there is one.
    Sampler actors are started inside `with ctx.reserve_samplers(n) as slots:`, which waits until the
    cluster fits them all at once.
    """

    job_id: str
    scene: SceneSpec
    scene_dir: Path | None
    config: BaseModel
    seed: int
    output_dir: Path
    checkpoints: CheckpointStore
    reserve_samplers: Callable[[int], AbstractContextManager[SamplerSlots]] = field(repr=False)
    on_progress: Callable[..., None] = field(repr=False)
    on_log: Callable[[str], None] = field(repr=False)
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
    """What a finished `run` leaves: artifact files (name -> (local path, media type)) and metrics."""

    files: dict[str, tuple[str, str]]
    metrics: dict[str, float]


@runtime_checkable
class ModelKind(Protocol):
    name: str
    config_model: type[BaseModel]  # extra="forbid"
    presets: dict[str, dict]  # "quick", "default", "paper"

    def resolve_config(self, preset: str, overrides: dict) -> BaseModel: ...

    def plan(self, scene: SceneSpec, config: BaseModel) -> Plan: ...

    def resources(self, config: BaseModel) -> Resources: ...

    def run(self, ctx: JobContext) -> RunOutput: ...


# ------------------------------------------------------------------ inference
# A kind that can be served sets `infer_module` (one line) to a module exposing `INFERENCE`, an object
# satisfying `Inference`; the inference service reads it through `get_inference` and never names a kind.

QUERY, RENDER = "query", "render"


@dataclass(frozen=True)
class ArraySpec:
    """One input array of an operation: the dtype it is converted to and its shape, `None` where any
    length goes. Axis 0 is the row axis that dynamic batching concatenates along."""

    dtype: str
    shape: tuple[int | None, ...]
    required: bool = True


@dataclass(frozen=True)
class Operation:
    """What an operation takes (typed parameters, input arrays) and whether concurrent requests with equal
    parameters may be merged row-wise into one call (`batched`), which only row-independent models allow."""

    params: type[BaseModel]
    inputs: Mapping[str, ArraySpec] = field(default_factory=dict)
    batched: bool = False


@dataclass
class Answer:
    """Output arrays (row-aligned with the inputs for a batched operation; `image` (H, W, C) float32
    linear for `render`) and JSON-serialisable metadata such as the names that indices refer to."""

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)


class LoadedModel(Protocol):
    """An artifact in memory, ready to answer; `nbytes` is what it holds, for the service's memory budget."""

    nbytes: int

    def answer(self, operation: str, params: BaseModel, arrays: dict[str, np.ndarray]) -> Answer: ...


class Inference(Protocol):
    """A kind's `infer`: the operations its artifacts answer and how to load one from its files."""

    operations: Mapping[str, Operation]

    def load(self, folder: Path, device: str) -> LoadedModel: ...


def get_inference(name: str) -> Inference | None:
    """The kind's inference (imported on first use), or None for a kind that cannot be served."""
    module = getattr(get_kind(name), "infer_module", None)
    return None if module is None else importlib.import_module(module).INFERENCE


def resolve_preset(
    config_model: type[BaseModel], presets: Mapping[str, dict], preset: str, overrides: dict
) -> BaseModel:
    """The preset's values with `overrides` merged in (nested dicts merge key by key), validated.

    Raises ValueError for an unknown preset and pydantic's ValidationError (naming the field) for bad values.
    """
    if preset not in presets:
        raise ValueError(f"unknown preset {preset!r}; known presets: {', '.join(presets)}")
    return config_model.model_validate(_merge(presets[preset], overrides or {}))


def _merge(base: dict, overrides: dict) -> dict:
    merged = dict(base)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


@cache
def _kinds() -> dict[str, ModelKind]:
    kinds = [importlib.import_module(module).KIND for module in KIND_MODULES]
    return {kind.name: kind for kind in kinds}


def kind_names() -> list[str]:
    return sorted(_kinds())


def get_kind(name: str) -> ModelKind:
    """The kind registered under `name`; UnknownKind (a KeyError) lists the known ones."""
    try:
        return _kinds()[name]
    except KeyError:
        raise UnknownKind(name) from None
