"""The `lod` method on the shared pipeline: voxelise the asset, train both networks on path-traced voxel
samples, optimise the per-voxel thresholds, export the artifact and measure every LoD.

The grid and the thresholds are rebuilt deterministically from the scene and the seed, so a restarted job
resumes its training steps from the checkpoints and repeats the rest exactly.
"""

from __future__ import annotations

import numpy as np
import torch

from workers.models.lod import artifact
from workers.models.lod.artifact import STORAGE_DTYPE, LodAsset, build_networks
from workers.models.lod.config import LodConfig
from workers.models.lod.evaluate import evaluate_levels
from workers.models.lod.grid import LodGrid
from workers.models.lod.plan import Asset, choose_asset, choose_resolutions, cube_extent
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_tracer, asset_triangles
from workers.models.lod.thresholds import optimise_thresholds
from workers.models.lod.train import lod_loss, per_network_step_seconds
from workers.runtime.contract import JobContext
from workers.runtime.pipeline import Finished, Trainable, Trained
from workers.runtime.sources import SourceSpec
from workers.runtime.training import Phase


class LodMethod:
    """One job's method: `trainables` chooses and voxelises the asset, which `finish` then exports."""

    kind = "lod"

    def __init__(self) -> None:
        self.asset: Asset | None = None
        self.grid: LodGrid | None = None

    def trainables(self, ctx: JobContext[LodConfig]) -> list[Trainable]:
        config = ctx.config
        self.asset = choose_asset(ctx.scene, config)
        self.grid = _voxelise(ctx, self.asset)
        torch.manual_seed(ctx.seed)
        networks = build_networks(config, self.grid)
        source = LodSourceConfig(ctx.scene, self.asset.names, config, self.grid.arrays())
        return [
            Trainable(
                networks,
                [Phase("main", lod_loss)],
                SourceSpec(LodSource, source, ctx.seed),
                config.train,
                stored_dtype=STORAGE_DTYPE,
            )
        ]

    def finish(self, ctx: JobContext[LodConfig], trained: list[Trained]) -> Finished:
        config = ctx.config
        (done,) = trained
        networks, chosen, grid = done.model, self.asset, self.grid
        scene = ctx.scene.compiled()
        step_seconds = per_network_step_seconds(
            networks, done.trainable.source.build().batch(done.result.steps)
        )
        ctx.log(f"optimising thresholds with {config.threshold_samples} samples per voxel")
        gains = optimise_thresholds(
            grid, networks.visibility, asset_tracer(scene, chosen.names), config.threshold_samples,
            config.threshold_candidates, np.random.default_rng([ctx.seed, 1]),
            on_level=lambda level: (ctx.raise_if_cancelled(), ctx.log(f"thresholds of LoD {level} done")),
        )  # fmt: skip
        asset = LodAsset(config, chosen.names, grid, networks)
        files = artifact.save(ctx.output_dir, asset, scene)

        ctx.log("measuring every LoD against path tracing")
        levels = evaluate_levels(
            scene, asset, ctx.seed,
            on_level=lambda level: (ctx.raise_if_cancelled(), ctx.log(f"LoD {level} measured")),
        )  # fmt: skip
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
            "training_seconds_visibility": step_seconds["visibility"] * done.result.steps,
            "training_seconds_appearance": step_seconds["appearance"] * done.result.steps,
        }
        for f in levels.figures:
            method_metrics.update(
                {f"lod{f.level}.{k}": float(v) for k, v in f.model_dump().items() if k != "level"}
            )
        metrics = {
            "flip_coarsest": levels.figures[-1].flip,
            "speedup_coarsest": levels.figures[-1].speedup_over_lod0,
            "storage_saving": storage["storage_saving"],
            "levels": float(grid.levels),
        }
        return Finished(files, levels.view, levels.frame, method_metrics, metrics)


def _voxelise(ctx: JobContext[LodConfig], chosen: Asset) -> LodGrid:
    """The planned LoDs of the chosen objects' triangles."""
    config = ctx.config
    scene = ctx.scene.compiled()
    extent = cube_extent(chosen.bounds, config.finest_resolution)
    resolutions = [r for r, _ in choose_resolutions(ctx.scene.spec, config, extent)]
    triangles = scene.positions[asset_triangles(scene, chosen.names)].astype(np.float64)
    ctx.log(f"voxelising {len(triangles):,} triangles of {', '.join(chosen.names)} at {resolutions}")
    grid = LodGrid.build(triangles, resolutions)
    occupied = ", ".join(f"{r}^3: {len(k):,}" for r, k in zip(resolutions, grid.keys, strict=True))
    ctx.log(f"occupied voxels per LoD: {occupied}")
    return grid
