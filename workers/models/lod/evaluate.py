"""What a `lod` artifact is worth, per LoD (Weier et al. 2023, Sec. 6): error against path tracing the
full geometry, render time, path length and storage.

- Error: FLIP (mean over pixels where the camera sees the asset) at the resolution where a voxel of the
  level is about one pixel, against a converged path-traced reference; with light sampling from voxels
  (beyond the paper) and without it (the paper's estimator).
- Speed: every level and plain path tracing at one common resolution (LoD 0's) and equal spp; the
  speed-up of each level over LoD 0, and the mean number of path segments over the asset's pixels
  (Fig. 15) against brute-force path tracing.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from pydantic import BaseModel

from workers.models.lod.artifact import LodAsset
from workers.models.lod.sampling import asset_tracer, asset_triangles
from workers.nn.metrics import flip
from workers.render.camera import PinholeCamera
from workers.render.embree import SubsetRayScene
from workers.render.integrator import PathTracer
from workers.render.render import RenderResult, RenderSettings, render
from workers.runtime.report import TimedImage
from workers.runtime.threads import torch_threads
from workers.runtime.view import PathTracedView
from workers.scene.geometry.compile import CompiledScene

MIN_HEIGHT = 16
MAX_DEPTH = 64  # the paper compares at unlimited depth; paths end by Russian roulette long before this


class LevelFigures(BaseModel):
    level: int
    resolution: int
    width: int
    height: int
    occupied_voxels: int
    occupancy: float
    flip: float
    flip_without_light_sampling: float
    seconds: float  # at the common resolution and spp
    path_tracing_seconds: float
    speedup_over_lod0: float = 1.0
    mean_path_length: float
    path_tracing_mean_path_length: float


def matched_size(scene: CompiledScene, asset: LodAsset, level: int, max_height: int) -> tuple[int, int]:
    """Image size at which a voxel of `level` covers about one pixel from the scene camera."""
    camera = scene.spec.camera
    centre = asset.grid.lo + asset.grid.extent / 2
    distance = float(np.linalg.norm(centre - np.asarray(camera.position)))
    footprint_at_one_pixel = 2 * distance * math.tan(math.radians(camera.fov) / 2)
    height = round(asset.grid.resolutions[level] * footprint_at_one_pixel / asset.grid.extent)
    height = int(np.clip(height, MIN_HEIGHT, max_height))
    return max(1, round(height * camera.width / camera.height)), height


def asset_mask(scene: CompiledScene, asset_only: PathTracer, width: int, height: int) -> np.ndarray:
    """Pixels whose centre sees the asset: FLIP is averaged over these, as in the paper's Fig. 16."""
    camera = PinholeCamera(scene.spec.camera, width, height)
    ys, xs = np.mgrid[0:height, 0:width]
    origins, directions = camera.rays(xs.ravel() + 0.5, ys.ravel() + 0.5)
    return asset_only.rays.intersect(origins, directions).found.reshape(height, width)


def lod_tracer(scene: CompiledScene, asset: LodAsset, level: int, **options) -> PathTracer:
    """The scene with its asset replaced by LoD `level`: Embree for everything else."""
    rest = np.setdiff1d(np.arange(len(scene.positions)), asset_triangles(scene, asset.objects))
    light_sampling = options.pop("light_sampling", True)
    return PathTracer(
        scene,
        intersector=SubsetRayScene(scene.positions, rest),
        aggregate=asset.aggregate(level, **options),
        aggregate_next_event=light_sampling,
    )


def timed_render(tracer: PathTracer, settings: RenderSettings) -> RenderResult:
    """`render` with the networks in inference mode and one torch thread per render thread."""
    with torch.inference_mode(), torch_threads(1):
        return render(tracer, settings)


@dataclass
class LevelEvaluation:
    figures: list[LevelFigures]
    view: PathTracedView  # LoD 0's view: the report's
    frame: TimedImage  # LoD 0 rendered of that view


def evaluate_levels(
    scene: CompiledScene,
    asset: LodAsset,
    seed: int = 0,
    on_level: Callable[[int], None] | None = None,
) -> LevelEvaluation:
    """Per-level figures (module docstring), and LoD 0's view and frame for the report."""
    config = asset.config
    reference_tracer = PathTracer(scene)
    common_w, common_h = matched_size(scene, asset, 0, config.evaluation_max_height)
    common = RenderSettings(
        spp=config.evaluation_spp, width=common_w, height=common_h, max_depth=MAX_DEPTH, seed=seed, aovs=True
    )
    views = {}
    asset_only = asset_tracer(scene, asset.objects)  # one BVH of the asset for every mask
    common_mask = asset_mask(scene, asset_only, common_w, common_h)
    traced = timed_render(reference_tracer, common)
    traced_length = masked_mean(traced.aovs["path_length"][..., 0], common_mask)
    figures, frame = [], None
    for level in range(asset.grid.levels):
        w, h = matched_size(scene, asset, level, config.evaluation_max_height)
        mask = asset_mask(scene, asset_only, w, h)
        at_level = common.model_copy(update={"width": w, "height": h})
        if (w, h) not in views:
            views[w, h] = PathTracedView(
                scene, at_level.model_copy(update={"aovs": False}), config.reference_spp, reference_tracer
            )
        reference = views[w, h].reference()
        with_nee = timed_render(lod_tracer(scene, asset, level), at_level)
        without_nee = timed_render(lod_tracer(scene, asset, level, light_sampling=False), at_level)
        timing = (
            with_nee
            if (w, h) == (common_w, common_h)
            else timed_render(lod_tracer(scene, asset, level), common)
        )
        figures.append(
            LevelFigures(
                level=level,
                resolution=asset.grid.resolutions[level],
                width=w,
                height=h,
                occupied_voxels=len(asset.grid.keys[level]),
                occupancy=asset.grid.occupancy(level),
                flip=flip(reference, with_nee.image, mask=mask),
                flip_without_light_sampling=flip(reference, without_nee.image, mask=mask),
                seconds=timing.seconds,
                path_tracing_seconds=traced.seconds,
                mean_path_length=masked_mean(timing.aovs["path_length"][..., 0], common_mask),
                path_tracing_mean_path_length=traced_length,
            )
        )
        if level == 0:
            frame = TimedImage(f"LoD 0, {config.evaluation_spp} spp", with_nee.image, with_nee.seconds)
        if on_level is not None:
            on_level(level)
    for f in figures:
        f.speedup_over_lod0 = figures[0].seconds / max(f.seconds, 1e-12)
    return LevelEvaluation(figures, views[common_w, common_h], frame)


def masked_mean(values: np.ndarray, mask: np.ndarray) -> float:
    """The mean of `values` where `mask` holds; NaN where it never does (no pixel sees the asset: nothing
    was measured, which must not read as a perfect score)."""
    return float(values[mask].mean()) if mask.any() else float("nan")
