"""Progressive, tiled image rendering on top of the path tracer.

Work is split into (pass, tile) items, each with its own random stream derived from
(seed, pass, tile), and summed in a fixed order: the image is identical for a seed whatever the
thread count. Memory stays bounded: one item traces at most `MAX_PATHS_PER_ITEM` paths.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.scene.compile import CompiledScene

MAX_PATHS_PER_ITEM = 1 << 16
AOV_NAMES = ("position", "normal", "albedo", "roughness", "depth", "emission")


class RenderSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    spp: int = Field(64, ge=1, le=1 << 20)
    width: int | None = Field(None, ge=1, le=16384, description="defaults to the scene camera's")
    height: int | None = Field(None, ge=1, le=16384)
    max_depth: int = Field(8, ge=1, le=1024)
    rr_depth: int = Field(5, ge=1)
    seed: int = Field(0, ge=0)
    tile_size: int = Field(64, ge=8, le=1024)
    threads: int = Field(2, ge=1, le=256)
    aovs: bool = False


@dataclass
class RenderProgress:
    samples_done: int
    samples_total: int
    elapsed: float
    rays_traced: int

    @property
    def fraction(self) -> float:
        return self.samples_done / self.samples_total


@dataclass
class RenderResult:
    image: np.ndarray  # (H, W, 3) float32 linear radiance
    spp: int
    seconds: float
    rays_traced: int
    aovs: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def rays_per_second(self) -> float:
        return self.rays_traced / max(self.seconds, 1e-12)


@dataclass(frozen=True)
class _Tile:
    index: int
    x0: int
    y0: int
    x1: int
    y1: int


def _tiles(width: int, height: int, size: int) -> list[_Tile]:
    tiles = []
    for y0 in range(0, height, size):
        for x0 in range(0, width, size):
            tiles.append(_Tile(len(tiles), x0, y0, min(x0 + size, width), min(y0 + size, height)))
    return tiles


def render(
    scene: CompiledScene | PathTracer,
    settings: RenderSettings | None = None,
    progress: Callable[[RenderProgress], None] | None = None,
) -> RenderResult:
    settings = settings or RenderSettings()
    tracer = scene if isinstance(scene, PathTracer) else PathTracer(scene)
    cam_spec = tracer.scene.spec.camera
    camera = PinholeCamera(cam_spec, settings.width, settings.height)
    width, height = camera.width, camera.height
    tiles = _tiles(width, height, settings.tile_size)
    tile_pixels = settings.tile_size**2
    spp_per_pass = int(np.clip(MAX_PATHS_PER_ITEM // tile_pixels, 1, settings.spp))
    passes = []
    done = 0
    while done < settings.spp:
        passes.append(min(spp_per_pass, settings.spp - done))
        done += passes[-1]

    accum = np.zeros((height, width, 3))
    aov_accum = {name: np.zeros((height, width, 3)) for name in AOV_NAMES} if settings.aovs else {}
    rays = 0
    start = time.perf_counter()

    def work(pass_index: int, spp: int, tile: _Tile):
        rng = np.random.default_rng([settings.seed, pass_index, tile.index])
        return _render_tile(tracer, camera, tile, spp, settings, rng)

    samples_done = 0
    with ThreadPoolExecutor(max_workers=settings.threads) as pool:
        for pass_index, spp in enumerate(passes):
            results = pool.map(lambda t, p=pass_index, s=spp: work(p, s, t), tiles)
            for tile, (radiance, aovs, tile_rays) in zip(tiles, results, strict=True):
                accum[tile.y0 : tile.y1, tile.x0 : tile.x1] += radiance
                for name, value in aovs.items():
                    aov_accum[name][tile.y0 : tile.y1, tile.x0 : tile.x1] += value
                rays += tile_rays
            samples_done += spp
            if progress is not None:
                progress(RenderProgress(samples_done, settings.spp, time.perf_counter() - start, rays))
    seconds = time.perf_counter() - start
    image = (accum / settings.spp).astype(np.float32)
    aov_images = {name: (value / settings.spp).astype(np.float32) for name, value in aov_accum.items()}
    return RenderResult(image, settings.spp, seconds, rays, aov_images)


def _render_tile(tracer: PathTracer, camera: PinholeCamera, tile: _Tile, spp: int, settings, rng):
    w, h = tile.x1 - tile.x0, tile.y1 - tile.y0
    ys, xs = np.mgrid[tile.y0 : tile.y1, tile.x0 : tile.x1]
    xs = np.repeat(xs.ravel(), spp)
    ys = np.repeat(ys.ravel(), spp)
    jitter = rng.random((len(xs), 2))
    origins, directions = camera.rays(xs + jitter[:, 0], ys + jitter[:, 1])
    result = tracer.trace(origins, directions, rng, settings.max_depth, settings.rr_depth)
    radiance = result.radiance.reshape(h, w, spp, 3).sum(axis=2)
    aovs = {}
    rays = result.rays_traced
    if settings.aovs:
        rec = tracer.first_hits(origins, directions)
        rays += len(origins)
        depth = np.where(rec.hit, rec.t, 0.0)
        per_sample = {
            "position": rec.position,
            "normal": rec.shading_normal,
            "albedo": rec.albedo,
            "roughness": np.repeat(rec.roughness[:, None], 3, axis=1),
            "depth": np.repeat(depth[:, None], 3, axis=1),
            "emission": rec.emission,
        }
        aovs = {k: v.reshape(h, w, spp, 3).sum(axis=2) for k, v in per_sample.items()}
    return radiance, aovs, rays
