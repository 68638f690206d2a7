"""Running a `lod` job: voxelise the asset, train both networks on batches path-traced by sampler actors,
optimise the per-voxel thresholds, export the artifact, and measure every LoD against path tracing.

Training checkpoints into the job's store, so a restarted job resumes its steps; the grid and the
thresholds are rebuilt deterministically from the scene and the seed.
"""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lod import artifact
from workers.models.lod.artifact import LodAsset, build_networks, round_to_storage
from workers.models.lod.config import LodConfig
from workers.models.lod.evaluate import MAX_DEPTH, evaluate_levels, timed_render
from workers.models.lod.grid import LodGrid
from workers.models.lod.networks import LodNetworks
from workers.models.lod.plan import Asset, choose_asset, choose_resolutions, cube_extent
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_tracer, asset_triangles
from workers.models.lod.thresholds import optimise_thresholds
from workers.models.lod.train import lod_loss, per_network_step_seconds
from workers.models.registry import JobContext, RunOutput
from workers.render.image_io import write_png
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings
from workers.runtime.report import TimedImage, build_report, nearest_in_time
from workers.runtime.samplers import open_batches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import TrainResult, train
from workers.scene.compile import CompiledScene, compile_scene

PATH_TRACING_SPP = (1, 4, 16, 64, 256)
PREVIEW = "preview.png"  # the reference and LoD 0 side by side


def run(ctx: JobContext) -> RunOutput:
    config: LodConfig = ctx.config
    scene = compile_scene(ctx.scene, ctx.scene_dir)
    chosen = choose_asset(ctx.scene, config, ctx.scene_dir)
    grid = _voxelise(ctx, scene, chosen)
    networks, training, step_seconds = _train(ctx, chosen, grid)

    ctx.log(f"optimising thresholds with {config.threshold_samples} samples per voxel")
    gains = optimise_thresholds(
        grid, networks.visibility, asset_tracer(scene, chosen.names), config.threshold_samples,
        config.threshold_candidates, np.random.default_rng([ctx.seed, 1]),
        on_level=lambda level: (ctx.raise_if_cancelled(), ctx.log(f"thresholds of LoD {level} done")),
    )  # fmt: skip
    asset = LodAsset(config, chosen.names, grid, networks)
    files = artifact.save(ctx.output_dir, asset)

    ctx.log("measuring every LoD against path tracing")
    figures, images = evaluate_levels(
        scene, asset, on_level=lambda level: (ctx.raise_if_cancelled(), ctx.log(f"LoD {level} measured"))
    )
    storage = {
        "network_bytes": float(asset.network_bytes()),
        "grid_bytes": float(grid.storage_bytes()),
        "asset_mesh_bytes": float(chosen.mesh_bytes),
    }
    stored = storage["network_bytes"] + storage["grid_bytes"]
    storage["storage_saving"] = 1 - stored / max(chosen.mesh_bytes, 1)
    method_metrics = {
        **storage,
        **gains,
        "training_seconds_visibility": step_seconds["visibility"] * training.steps,
        "training_seconds_appearance": step_seconds["appearance"] * training.steps,
    }
    for f in figures:
        method_metrics.update(
            {f"lod{f.level}.{k}": float(v) for k, v in f.model_dump().items() if k != "level"}
        )
    reference, lod_frame = images["reference"].image, images["lod"]
    traced = _path_traced_frames(scene, *reference.shape[:2])
    report = build_report(
        "lod",
        training,
        networks,
        lod_frame,
        nearest_in_time(traced, lod_frame.seconds),
        traced,
        reference,
        method_metrics=method_metrics,
    )
    files.update(report.write(str(ctx.output_dir)))
    write_png(ctx.output_dir / PREVIEW, np.concatenate([reference, lod_frame.image], 1))
    files[PREVIEW] = (str(ctx.output_dir / PREVIEW), "image/png")
    metrics = {
        "flip": figures[0].flip,
        "flip_coarsest": figures[-1].flip,
        "speedup_coarsest": figures[-1].speedup_over_lod0,
        "storage_saving": storage["storage_saving"],
        "levels": float(grid.levels),
    }
    return RunOutput(files=files, metrics=metrics)


def _voxelise(ctx: JobContext, scene: CompiledScene, chosen: Asset) -> LodGrid:
    """The planned LoDs of the chosen objects' triangles."""
    config: LodConfig = ctx.config
    extent = cube_extent(chosen.bounds, config.finest_resolution)
    resolutions = [r for r, _ in choose_resolutions(ctx.scene, config, extent)]
    triangles = scene.positions[asset_triangles(scene, chosen.names)].astype(np.float64)
    ctx.log(f"voxelising {len(triangles):,} triangles of {', '.join(chosen.names)} at {resolutions}")
    grid = LodGrid.build(triangles, resolutions)
    occupied = ", ".join(f"{r}^3: {len(k):,}" for r, k in zip(resolutions, grid.keys, strict=True))
    ctx.log(f"occupied voxels per LoD: {occupied}")
    return grid


def _train(
    ctx: JobContext, chosen: Asset, grid: LodGrid
) -> tuple[LodNetworks, TrainResult, dict[str, float]]:
    """Both networks trained on the job's sampler actors (resuming from the job's checkpoints), rounded to
    their stored precision, with each network's share of a step's time."""
    config: LodConfig = ctx.config
    torch.manual_seed(ctx.seed)
    networks = build_networks(config, grid)
    scene_dir = None if ctx.scene_dir is None else str(ctx.scene_dir)
    source = LodSourceConfig(
        ctx.scene.model_dump(mode="json"), scene_dir, chosen.names, config, grid.arrays()
    )
    spec = SourceSpec(LodSource, source, ctx.seed)

    def progress(p):
        ctx.raise_if_cancelled()
        ctx.progress(p.step, p.total_steps, loss=p.loss, samples_per_s=p.samples_per_s, eta_s=p.eta_s)

    with ctx.reserve_samplers(config.samplers) as slots:
        ctx.log(f"training on {slots.count or 'no'} sampler actor(s)")
        with open_batches(spec, slots.count, placement=slots.actor_options) as batches:
            training = train(networks, lod_loss, batches, config.train, ctx.checkpoints, progress)
            step_seconds = per_network_step_seconds(networks, next(batches))
    round_to_storage(networks)
    return networks.eval(), training, step_seconds


def _path_traced_frames(scene: CompiledScene, height: int, width: int) -> list[TimedImage]:
    """The full geometry path-traced at `PATH_TRACING_SPP`: the report's speed-against-error curve."""
    tracer = PathTracer(scene)
    frames = []
    for spp in PATH_TRACING_SPP:
        settings = RenderSettings(spp=spp, width=width, height=height, max_depth=MAX_DEPTH)
        result = timed_render(tracer, settings)
        frames.append(TimedImage(f"{spp} spp", result.image, result.seconds))
    return frames
