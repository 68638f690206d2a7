"""A render's resume point: the float64 sums after a whole number of passes, as safetensors + JSON.

Sums (not means) are stored in full precision, so a resumed render adds the remaining passes to exactly
the numbers the uninterrupted one had and ends bit-identical to it.
"""

from __future__ import annotations

import json

import numpy as np
import safetensors.numpy
from pydantic import BaseModel

from workers.render.render import ImageAccumulator, RenderSettings
from workers.runtime.checkpoints import CheckpointStore

SUMS_FILE = "sums.safetensors"
STATE_FILE = "state.json"
RADIANCE = "radiance"


class RenderState(BaseModel):
    passes_done: int
    rays_traced: int
    seconds: float  # render time spent before this checkpoint, over every earlier run
    settings: RenderSettings  # to refuse a checkpoint written for another image


def save(store: CheckpointStore, state: RenderState, accum: ImageAccumulator) -> None:
    tensors = {RADIANCE: accum.radiance, **{f"aov.{k}": v for k, v in accum.aovs.items()}}
    files = {SUMS_FILE: safetensors.numpy.save(tensors), STATE_FILE: state.model_dump_json().encode()}
    store.save(state.passes_done, files)


def restore(store: CheckpointStore, settings: RenderSettings, accum: ImageAccumulator) -> RenderState | None:
    """Load the latest checkpoint into `accum` (in place); None when there is none to resume from."""
    latest = store.latest()
    if latest is None:
        return None
    files = store.load(latest)
    state = RenderState.model_validate(json.loads(files[STATE_FILE]))
    if state.settings != settings:
        raise ValueError(
            f"the checkpoint in {store.root} was written for other render settings "
            f"({state.settings.model_dump()}); clear it to start this render afresh"
        )
    tensors = safetensors.numpy.load(files[SUMS_FILE])
    np.copyto(accum.radiance, tensors[RADIANCE])
    for name, value in accum.aovs.items():
        np.copyto(value, tensors[f"aov.{name}"])
    accum.rays_traced = state.rays_traced
    return state
