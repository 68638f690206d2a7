"""Quality gates: what a trained model must beat to be usable, as checks on its figures.

The integration tests run them on each kind's trained quick-preset model, and the fault-injection tests
run the same functions on doctored models (a black appearance, an object that never reports a hit, a NaN
frame) to show that every check fails on the fault it is meant to catch. A gate returns the checks that
failed, by name, with the figures that failed them: an empty dict means usable. Every comparison is
written so that NaN fails it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from workers.models.lod.artifact import LodAsset
from workers.models.lod.evaluate import (
    MAX_DEPTH,
    asset_mask,
    lod_tracer,
    masked_mean,
    matched_size,
    timed_render,
)
from workers.models.lod.sampling import asset_tracer
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings
from workers.runtime.report import Report
from workers.scene.geometry.compile import CompiledScene

# lsnif, against "always miss" (on the instanced ball: occlusion 0.85 overall, 0.78 in voxels, no normals)
HIT_RATE_TOLERANCE = 0.05  # |predicted - true| fraction of held-out rays that hit
MIN_OCCLUSION_IN_VOXELS = 0.9
MAX_NORMAL_ERROR_DEG = 35.0
LSNIF_CHECKS = ("hit_rate", "occlusion_in_voxels", "normal_error")

# lod, per level, against a black asset (FLIP ~0.95, paths end at the first bounce)
MAX_LOD_FLIP = 0.5
RADIANCE_RATIO = (0.5, 1.5)  # the asset's mean radiance over path tracing's
PATH_LENGTH_TOLERANCE = 0.3  # relative to path tracing's mean path length over the asset's pixels
LOD_CHECKS = ("flip", "mean_radiance", "path_length")

REPORT_CHECKS = ("finite_flip", "beats_one_spp")


def prefixed(figures: Mapping[str, float], prefix: str) -> dict[str, float]:
    """The figures named `<prefix>.<figure>` (a report's `method_metrics`), by figure."""
    return {k.removeprefix(f"{prefix}."): v for k, v in figures.items() if k.startswith(f"{prefix}.")}


def _failed(checks: Mapping[str, tuple[bool, str]]) -> dict[str, str]:
    return {name: text for name, (passed, text) in checks.items() if not passed}


def lsnif_failures(held_out: Mapping[str, float]) -> dict[str, str]:
    """The checks one LSNIF object's held-out figures (`workers.models.lsnif.evaluate.HeldOut`) fail."""
    hits, truth = held_out["hit_rate"], held_out["reference_hit_rate"]
    in_voxels, normal = held_out["occlusion_accuracy_in_voxels"], held_out["normal_error_deg"]
    return _failed(
        {
            "hit_rate": (abs(hits - truth) <= HIT_RATE_TOLERANCE, f"hit rate {hits:.3f}, truth {truth:.3f}"),
            "occlusion_in_voxels": (
                in_voxels > MIN_OCCLUSION_IN_VOXELS,
                f"occlusion accuracy in voxels {in_voxels:.3f} <= {MIN_OCCLUSION_IN_VOXELS}",
            ),
            "normal_error": (normal < MAX_NORMAL_ERROR_DEG, f"normal error {normal:.1f} deg"),
        }
    )


def lod_failures(level: Mapping[str, float]) -> dict[str, str]:
    """The checks one LoD's figures (`LevelFigures` plus `asset_radiance`'s) fail."""
    flip = level["flip"]
    traced_radiance = level["path_tracing_mean_radiance"]
    radiance = level["mean_radiance"] / traced_radiance if traced_radiance else math.nan
    length, traced = level["mean_path_length"], level["path_tracing_mean_path_length"]
    low, high = RADIANCE_RATIO
    return _failed(
        {
            "flip": (flip < MAX_LOD_FLIP, f"FLIP {flip:.3f}"),
            "mean_radiance": (low <= radiance <= high, f"mean radiance {radiance:.3f} x path tracing's"),
            "path_length": (
                abs(length - traced) <= PATH_LENGTH_TOLERANCE * traced,
                f"mean path length {length:.2f}, path tracing {traced:.2f}",
            ),
        }
    )


def report_failures(report: Report) -> dict[str, str]:
    """The checks any kind's report fails: a finite FLIP, better than 1-spp path tracing of its view."""
    flip = report.model.error.flip
    return _failed(
        {
            "finite_flip": (math.isfinite(flip), f"FLIP {flip}"),
            "beats_one_spp": (not report.worse_than_one_spp, "; ".join(report.warnings())),
        }
    )


def asset_radiance(scene: CompiledScene, asset: LodAsset, level: int, seed: int = 0) -> dict[str, float]:
    """Mean radiance over the pixels that see the asset, LoD `level` against path tracing, both at the
    config's `reference_spp` and at the size where a voxel of LoD 0 is about a pixel (the finest size
    `evaluate_levels` measures at): a mean over that many paths needs no converged image."""
    config = asset.config
    width, height = matched_size(scene, asset, 0, config.evaluation_max_height)
    mask = asset_mask(scene, asset_tracer(scene, asset.objects), width, height)
    settings = RenderSettings(
        spp=config.reference_spp, width=width, height=height, max_depth=MAX_DEPTH, seed=seed, threads=1
    )
    model = timed_render(lod_tracer(scene, asset, level), settings).image
    traced = timed_render(PathTracer(scene), settings).image
    return {
        "mean_radiance": masked_mean(model.mean(-1), mask),
        "path_tracing_mean_radiance": masked_mean(traced.mean(-1), mask),
    }
