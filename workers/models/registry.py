"""The one place that knows every model kind: the job server, the driver and the inference service look
kinds up here by name, so adding a kind is one line in `KIND_MODULES` and no `if kind == ...` elsewhere.

Kinds are imported on first lookup, not when this module is imported: the server validates configs
without loading the path tracer or torch until a kind is actually asked for.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from pydantic import BaseModel

from workers.render.aggregate_materials import register_aggregate_material
from workers.runtime.contract import PRESET_NAMES, Kind

if TYPE_CHECKING:
    import numpy as np

# One line per kind: a module exposing `KIND`, a `workers.runtime.contract.Kind` declaration.
KIND_MODULES = (
    "workers.models.render",
    "workers.models.lsnif",
    "workers.models.lod",
    "workers.models.mesogan",
    "workers.models.prt",
    "workers.models.explore",
)
__all__ = [
    "PRESET_NAMES",
    "Kind",
    "UnknownKind",
    "get_inference",
    "get_kind",
    "kind_names",
    "material_kind",
    "register_materials",
]


class UnknownKind(KeyError):
    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.name = name

    def __str__(self) -> str:
        return f"unknown model kind {self.name!r}; known kinds: {', '.join(kind_names())}"


# ------------------------------------------------------------------ inference
# A kind that can be served sets `infer_module` (one line) to a module exposing `INFERENCE`, an object
# satisfying `Inference`; the inference service reads it through `get_inference` and never names a kind.

QUERY, RENDER = "query", "render"


@dataclass(frozen=True)
class ArraySpec:
    """One input array of an operation: the dtype it is converted to and its shape, `None` where any
    length goes. Axis 0 is the row axis that dynamic batching concatenates along, unless `per_call`: an
    input the whole call shares (an environment map beside a batched query's points), which is never
    split or merged, and a request carrying one runs alone."""

    dtype: str
    shape: tuple[int | None, ...]
    required: bool = True
    per_call: bool = False

    @property
    def rows(self) -> bool:
        """Whether axis 0 counts rows: any length, and not `per_call`."""
        return self.shape[:1] == (None,) and not self.per_call


@dataclass(frozen=True)
class Operation:
    """What an operation takes (typed parameters, input arrays) and whether concurrent requests with equal
    parameters may be merged row-wise into one call (`batched`), which only row-independent models allow.

    The memory one request needs, which the inference service admits before running it, beyond its
    inputs: `row_bytes` per input row for as long as the answer lives (the outputs and their encoded
    copy), `activation_row_bytes` per row of the chunk being computed (intermediate arrays, network
    activations; a batched operation runs at most the service's `chunk_rows` rows at a time), and
    `call_bytes` once per call (an image, a whole stored layer), and `params_bytes(model, params)` for
    what the typed parameters ask of the loaded model (a generated window of as many texels as they say).
    Upper estimates, each kind's own, with how they were found beside them;
    `python -m tests.bench bench_inference_memory` measures the measured kinds' peaks against them."""

    params: type[BaseModel]
    inputs: Mapping[str, ArraySpec] = field(default_factory=dict)
    batched: bool = False
    row_bytes: int = 0
    activation_row_bytes: int = 0
    call_bytes: int = 0
    params_bytes: Callable[[Any, BaseModel], int] = lambda model, params: 0


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


@cache
def _kinds() -> dict[str, Kind]:
    kinds = [importlib.import_module(module).KIND for module in KIND_MODULES]
    for kind in kinds:
        for material, builder in kind.materials.items():
            register_aggregate_material(material, builder)
    return {kind.name: kind for kind in kinds}


def register_materials() -> None:
    """Register the scene materials the kinds draw (`Kind.materials`) with the path tracer: done by the
    first kind lookup, and by whatever renders a scene outside a job (`nbake render`, a sampler actor)."""
    _kinds()


def material_kind(material_type: str) -> str | None:
    """The kind whose artifacts a scene material of `material_type` draws: the one declaring it in
    `Kind.materials` (None: no kind does)."""
    return next((kind.name for kind in _kinds().values() if material_type in kind.materials), None)


def kind_names() -> list[str]:
    return sorted(_kinds())


def get_kind(name: str) -> Kind:
    """The kind registered under `name`; UnknownKind (a KeyError) lists the known ones."""
    try:
        return _kinds()[name]
    except KeyError:
        raise UnknownKind(name) from None
