"""Progressive, tiled image rendering on top of the path tracer.

Work is split into (pass, tile) items, each with its own random stream derived from
(seed, pass, tile), and summed in a fixed order: the image is identical for a seed whatever the
number of workers. Memory stays bounded: one item traces at most `MAX_PATHS_PER_ITEM` paths.
Workers are threads: Embree and NumPy release the GIL, and on an idle 2-core machine two threads
trace 1.9x the rays of one (forked processes measured no better).
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.render.stratified import StratifiedUniforms
from workers.scene.format.spec import Camera
from workers.scene.geometry.compile import CompiledScene

MAX_PATHS_PER_ITEM = 1 << 16
AOV_NAMES = ("position", "normal", "albedo", "roughness", "depth", "emission", "path_length")
# Stored three times in `aovs`, written as one channel; path_length is the mean number of path segments.
SCALAR_AOVS = frozenset({"roughness", "depth", "path_length"})


class RenderSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    spp: int = Field(64, ge=1, le=1 << 20)
    width: int | None = Field(None, ge=1, le=16384, description="defaults to the scene camera's")
    height: int | None = Field(None, ge=1, le=16384)
    max_depth: int = Field(8, ge=1, le=1024)
    rr_depth: int = Field(5, ge=1)
    seed: int = Field(0, ge=0)
    tile_size: int = Field(64, ge=8, le=1024)
    # Two (1.9x the rays of one on this idle 2-core machine). One stop (2026-12-01, early) saw renders on
    # two threads crash inside jobs (abort, bus error, "malloc(): unaligned tcache chunk detected") in CI
    # twice and in 3 of 3 fresh-clone runs of test_inference_server, and made one the default; on the next
    # stop's fresh machine the same test passed 6 of 6 times with cold kernel caches and the whole suite
    # once (14 min, against 32 on one thread), so two are back. Cause not found: see both stops' notes.
    threads: int = Field(2, ge=1, le=256)
    aovs: bool = False
    window: tuple[int, int, int, int] | None = Field(
        None, description="render only pixels x0 <= x < x1, y0 <= y < y1 of the image (a crop window)"
    )
    pixel_samples: Literal["area", "centre"] = Field(
        "area",
        description="area: jittered over each pixel (a box filter); centre: every sample through the "
        "pixel's centre, the point first-hit G-buffers describe (`workers.render.gbuffer`)",
    )
    sampler: Literal["independent", "stratified"] = Field(
        "independent",
        description="stratified: a pixel's samples in a pass lie in strata at the camera and the first "
        "vertex (`workers.render.stratified`), and tiles shrink so that a pass holds all of them",
    )


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

    def aov_images(self) -> dict[str, np.ndarray]:
        """G-buffers as written to files: RGB, or (H, W) for the scalar ones."""
        return {name: value[..., 0] if name in SCALAR_AOVS else value for name, value in self.aovs.items()}


@dataclass(frozen=True)
class Tile:
    index: int
    x0: int
    y0: int
    x1: int
    y1: int


@dataclass(frozen=True)
class RenderPlan:
    """The work of one image: every pass renders every tile; items are independent and seeded."""

    width: int
    height: int
    tiles: list[Tile]
    passes: list[int]  # samples per pixel of each pass
    x0: int = 0  # the crop window's corner: tiles are in image pixels, the image starts here
    y0: int = 0

    @property
    def items(self) -> list[tuple[int, Tile]]:
        return [(p, t) for p in range(len(self.passes)) for t in self.tiles]


@dataclass
class TileResult:
    """Sums (not means) over the pass's samples, so passes add up."""

    radiance: np.ndarray  # (h, w, 3) float64
    aovs: dict[str, np.ndarray]
    rays_traced: int


def crop_window(camera: PinholeCamera, settings: RenderSettings) -> tuple[int, int, int, int]:
    """The pixels to render, (x0, y0, x1, y1): the settings' window, checked to lie in the image, or all."""
    if settings.window is None:
        return 0, 0, camera.width, camera.height
    x0, y0, x1, y1 = settings.window
    if not (0 <= x0 < x1 <= camera.width and 0 <= y0 < y1 <= camera.height):
        raise ValueError(
            f"window: {settings.window} is not a non-empty window of the {camera.width}x{camera.height} image"
        )
    return x0, y0, x1, y1


def plan_render(camera: PinholeCamera, settings: RenderSettings) -> RenderPlan:
    """Tiles over the crop window (the whole image by default); each pixel is sampled as in a full render,
    so a window's expected value is the crop of the full image's."""
    x_start, y_start, x_stop, y_stop = crop_window(camera, settings)
    width, height, size = x_stop - x_start, y_stop - y_start, settings.tile_size
    if settings.sampler == "stratified":  # the largest tile (down to 8) whose pass holds every sample
        per_pixel = math.isqrt(max(1, MAX_PATHS_PER_ITEM // settings.spp))
        size = min(size, max(8, 1 << (per_pixel.bit_length() - 1)))
    tiles = []
    for y0 in range(y_start, y_stop, size):
        for x0 in range(x_start, x_stop, size):
            tiles.append(Tile(len(tiles), x0, y0, min(x0 + size, x_stop), min(y0 + size, y_stop)))
    spp_per_pass = int(np.clip(MAX_PATHS_PER_ITEM // size**2, 1, settings.spp))
    passes, done = [], 0
    while done < settings.spp:
        passes.append(min(spp_per_pass, settings.spp - done))
        done += passes[-1]
    return RenderPlan(width, height, tiles, passes, x_start, y_start)


def render_item(
    tracer: PathTracer,
    camera: PinholeCamera,
    settings: RenderSettings,
    plan: RenderPlan,
    pass_index: int,
    tile: Tile,
) -> TileResult:
    """One (pass, tile) work item with its own random stream: the same result wherever it runs."""
    rng = np.random.default_rng([settings.seed, pass_index, tile.index])
    spp = plan.passes[pass_index]
    if settings.sampler == "stratified":
        rng = StratifiedUniforms(rng, (tile.x1 - tile.x0) * (tile.y1 - tile.y0), spp)
    return _render_tile(tracer, camera, tile, spp, settings, rng)


def rendered_view(camera: Camera, settings: RenderSettings) -> Camera:
    """`camera` at the size `settings` render it (what `PathTracer`'s `view` is)."""
    size = {"width": settings.width or camera.width, "height": settings.height or camera.height}
    return camera.model_copy(update=size)


def render(
    scene: CompiledScene | PathTracer,
    settings: RenderSettings | None = None,
    progress: Callable[[RenderProgress], None] | None = None,
    view: Camera | None = None,
) -> RenderResult:
    """An image of the scene through `view` (default: the scene camera)."""
    settings = settings or RenderSettings()
    if isinstance(scene, PathTracer):
        tracer = scene
    else:
        tracer = PathTracer(scene, view=rendered_view(view or scene.spec.camera, settings))
    camera = PinholeCamera(view or tracer.scene.spec.camera, settings.width, settings.height)
    plan = plan_render(camera, settings)
    accum = ImageAccumulator(plan, settings.aovs)
    start = time.perf_counter()
    samples_done = 0

    def add_pass(pass_index: int, results: list[Future]) -> None:
        nonlocal samples_done
        for tile, result in zip(plan.tiles, results, strict=True):
            accum.add(tile, result.result())
        samples_done += plan.passes[pass_index]
        if progress is not None:
            progress(
                RenderProgress(samples_done, settings.spp, time.perf_counter() - start, accum.rays_traced)
            )

    # A pass is summed once the next one is queued: a thread done with its last item of a pass starts on
    # the next pass instead of idling until the pass's slowest item ends (cornell_box 128^2 at 64 spp, 4
    # passes of 4 tiles on 2 threads, scheduled from measured item CPU times: 1.020x -> 1.006x the ideal
    # makespan). Sums stay in (pass, tile) order, so the image is unchanged; two passes at most in flight.
    with ThreadPoolExecutor(max_workers=settings.threads) as pool:
        try:
            queued: deque[tuple[int, list[Future]]] = deque()
            for pass_index in range(len(plan.passes)):
                work = partial(render_item, tracer, camera, settings, plan, pass_index)
                queued.append((pass_index, [pool.submit(work, tile) for tile in plan.tiles]))
                if len(queued) == 2:
                    add_pass(*queued.popleft())
            while queued:
                add_pass(*queued.popleft())
        except BaseException:
            pool.shutdown(cancel_futures=True)  # an item failed: drop the items not started
            raise
    return accum.result(settings.spp, time.perf_counter() - start)


class ImageAccumulator:
    """Sums tile results into full images; adding in a fixed order keeps the result bit-exact."""

    def __init__(self, plan: RenderPlan, aovs: bool):
        shape = (plan.height, plan.width, 3)
        self.radiance = np.zeros(shape)
        self.aovs = {name: np.zeros(shape) for name in AOV_NAMES} if aovs else {}
        self.rays_traced = 0
        self.x0, self.y0 = plan.x0, plan.y0

    def add(self, tile: Tile, result: TileResult) -> None:
        window = (slice(tile.y0 - self.y0, tile.y1 - self.y0), slice(tile.x0 - self.x0, tile.x1 - self.x0))
        self.radiance[window] += result.radiance
        for name, value in result.aovs.items():
            self.aovs[name][window] += value
        self.rays_traced += result.rays_traced

    def result(self, spp: int, seconds: float) -> RenderResult:
        image = (self.radiance / spp).astype(np.float32)
        aovs = {name: (value / spp).astype(np.float32) for name, value in self.aovs.items()}
        return RenderResult(image, spp, seconds, self.rays_traced, aovs)


def _render_tile(
    tracer: PathTracer, camera: PinholeCamera, tile: Tile, spp: int, settings, rng
) -> TileResult:
    w, h = tile.x1 - tile.x0, tile.y1 - tile.y0
    ys, xs = np.mgrid[tile.y0 : tile.y1, tile.x0 : tile.x1]
    xs = np.repeat(xs.ravel(), spp)
    ys = np.repeat(ys.ravel(), spp)
    jitter = rng.jitter() if isinstance(rng, StratifiedUniforms) else rng.random((len(xs), 2))
    if settings.pixel_samples == "centre":
        jitter = np.full_like(jitter, 0.5)  # drawn all the same, so the paths' random streams do not shift
    origins, directions = camera.rays(xs + jitter[:, 0], ys + jitter[:, 1])
    result = tracer.trace(
        origins, directions, rng, settings.max_depth, settings.rr_depth, spread=camera.spread
    )
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
            "path_length": np.repeat(result.bounces[:, None].astype(np.float64), 3, axis=1),
        }
        aovs = {k: v.reshape(h, w, spp, 3).sum(axis=2) for k, v in per_sample.items()}
    return TileResult(radiance, aovs, rays)
