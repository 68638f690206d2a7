"""Training patches of a variable scene: G-buffers and path-traced radiance of a crop of an R x R image.

A `PatchRequest` names everything a patch depends on (scene vector, resolution, patch corner, its render
seed), so `PatchSource.render` is a pure function of it and any sampler actor renders the same patch.
`batch(index)` is the seed-indexed form: `chains` uniform states at the starting resolution, the same for
the same (seed, index), which the uniform baseline's first batches and the runtime's contract use.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from workers.models.explore.config import ExploreConfig
from workers.models.explore.exploration import patch_origin
from workers.models.explore.features import pixel_features
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.render.render import RenderSettings, render
from workers.render.variable_tracer import VariableTracer
from workers.runtime.sources import Batch, batch_rng
from workers.scene.geometry.variable_scene import CompiledVariableScene
from workers.scene.portability.reference import SceneRef


@dataclass(frozen=True)
class PatchRequest:
    v: tuple[float, ...]
    resolution: int
    x0: int
    y0: int
    seed: int  # of the path tracer's random streams for this patch


def render_seed(*entropy: int) -> int:
    """A render seed for the patch named by `entropy` (job seed, iteration, chain, ...)."""
    return int(np.random.SeedSequence(list(entropy)).generate_state(1)[0])


def demodulated(radiance: np.ndarray, throughput: np.ndarray) -> np.ndarray:
    """The radiance leaving the G-buffers' surface: the pixel's over the mirrors' throughput it is seen
    through (`primary_gbuffers`), 0 where a mirror's colour is 0 (the pixel is black whatever it is)."""
    safe = np.where(throughput > 0, throughput, 1.0)
    return np.where(throughput > 0, radiance / safe, 0.0).astype(np.float32)


def request_for(state: np.ndarray, resolution: int, patch: int, seed: int) -> PatchRequest:
    """The patch of state u = (v, patch position) at resolution R."""
    x0, y0 = patch_origin(state[-2:], resolution, patch)
    return PatchRequest(tuple(float(x) for x in state[:-2]), resolution, x0, y0, seed)


@dataclass(frozen=True)
class PatchSourceConfig:
    scene: SceneRef
    explore: ExploreConfig


class PatchSource:
    """Renders patches of the scene (a `RequestSource`) and seed-indexed batches of uniform patches."""

    def __init__(self, config: PatchSourceConfig, seed: int) -> None:
        self.config = config
        self.seed = seed
        self.scene = CompiledVariableScene(config.scene.spec, config.scene.local_folder())
        self.tracer = VariableTracer(self.scene)
        self.box = self.scene.base.bounds

    @cached_property
    def dimensions(self) -> int:
        return self.scene.dimensions

    def render(self, request: PatchRequest) -> Batch:
        c = self.config.explore
        state = self.scene.at(request.v)
        tracer = self.tracer.state_tracer(state)
        camera = PinholeCamera(state.compiled.spec.camera, request.resolution, request.resolution)
        window = (request.x0, request.y0, request.x0 + c.patch, request.y0 + c.patch)
        buffers = primary_gbuffers(tracer, camera, window, mirror_bounces=c.mirror_bounces)
        settings = RenderSettings(
            spp=c.spp, width=request.resolution, height=request.resolution, max_depth=c.max_depth,
            seed=request.seed, threads=1, tile_size=max(c.patch, 8), window=window,
            pixel_samples=c.target_pixel_samples,
        )  # fmt: skip
        radiance = render(tracer, settings, view=state.compiled.spec.camera).image
        return {
            "features": torch.from_numpy(pixel_features(buffers, self.box, state.v)),
            "emission": torch.from_numpy(buffers.emission),
            "target": torch.from_numpy(demodulated(radiance, buffers.throughput)),
        }

    def batch(self, index: int) -> Batch:
        c = self.config.explore
        rng = batch_rng(self.seed, index)
        states = rng.random((c.chains, self.dimensions + 2))
        patches = [
            self.render(request_for(s, c.resolution_start, c.patch, render_seed(self.seed, index, k)))
            for k, s in enumerate(states)
        ]
        return {name: torch.stack([p[name] for p in patches]) for name in patches[0]}
