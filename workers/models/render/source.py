"""Render work items as a sample source, so the runtime's sampler pool runs them in Ray actors.

Batch i is plan item i (pass-major, then tile), a pure function of the seed: a replacement actor renders
exactly what a dead one owed, and the driver adds batches in index order, as the in-process renderer does.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from workers.models.registry import register_materials
from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, TileResult, plan_render, render_item, rendered_view
from workers.runtime.sources import Batch
from workers.scene.portability.reference import SceneRef

RADIANCE = "radiance"
RAYS = "rays_traced"
AOV_PREFIX = "aov."


@dataclass(frozen=True)
class TileSourceConfig:
    scene: SceneRef
    settings: RenderSettings


class TileSource:
    """Compiles the scene once per process and renders (pass, tile) items by their plan index."""

    def __init__(self, config: TileSourceConfig, seed: int) -> None:
        self.settings = config.settings.model_copy(update={"seed": seed})
        register_materials()
        view = rendered_view(config.scene.spec.camera, self.settings)
        self.tracer = PathTracer(config.scene.compiled(), view=view)
        self.camera = PinholeCamera(config.scene.spec.camera, self.settings.width, self.settings.height)
        self.plan = plan_render(self.camera, self.settings)
        self.items = self.plan.items

    def batch(self, index: int) -> Batch:
        if index >= len(self.items):
            return {}  # the sampler pool reads ahead of the consumer, past the last item too
        pass_index, tile = self.items[index]
        result = render_item(self.tracer, self.camera, self.settings, self.plan, pass_index, tile)
        return to_batch(result)


def to_batch(result: TileResult) -> Batch:
    """Tile sums as float64 tensors (exact: adding them reproduces the in-process sums bit for bit)."""
    batch = {RADIANCE: torch.from_numpy(result.radiance), RAYS: torch.tensor(result.rays_traced)}
    batch.update({AOV_PREFIX + name: torch.from_numpy(value) for name, value in result.aovs.items()})
    return batch


def from_batch(batch: Batch) -> TileResult:
    aovs = {k.removeprefix(AOV_PREFIX): v.numpy() for k, v in batch.items() if k.startswith(AOV_PREFIX)}
    return TileResult(batch[RADIANCE].numpy(), aovs, int(batch[RAYS]))
