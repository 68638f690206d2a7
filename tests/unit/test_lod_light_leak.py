"""The light-leak test of Weier et al. 2023 (Fig. 10) on the built-in `closed_box`: from inside a sealed
thin-walled box under a constant (6, 4, 2) environment the correct image is black, so the mean radiance of
a rendered LoD is the energy that leaked through the walls. The `lod` networks are trained briefly and the
inside view is rendered with the per-voxel optimal thresholds (Sec. 4.4) and with a fixed 0.5.

Settings, and why (measured with this code over seeds 0-9, 120 steps; ~3 s a run on one core):

- The visibility hash table has 2^8 rows (2 features per level): the paper attributes the leaks optimal
  thresholds remove to hash collisions (Fig. 9, 10). With the `quick` table (2^14) the classifier stops
  nearly every camera ray (seeds 0-3: 0.000-0.016 with optimal thresholds vs 0.003-0.031 fixed, out of an
  environment of mean 4) and the full image's leak (~0.4, see below) is the appearance network's, where the
  sign of the difference is noise (seed 3: 0.404 optimal vs 0.397 fixed); 2^10 is in between and mixed.
  The appearance network keeps the `quick` sizes.
- LoD 0 is 16^3 (a coarse LoD: a voxel is 6.6 x the wall thickness); 8^3 is built for the joint training
  but not measured: there the camera sits inside an occupied wall voxel, and traversal classifies the
  segment from the camera (not a boundary point) to the voxel's exit, which the networks never saw in
  training; whether the camera rays then scatter at the camera or pass depends on the seed.
- Two depths. max_depth 1 (camera rays only) measures visibility alone: the environment seen straight
  through the walls. max_depth 8 is the full image; it also holds leaks no threshold can remove: every wall
  of the box lies in the outermost voxel layer, so a path scattering in a wall voxel and continuing outwards
  starts past the wall, and only phi(w_o, w_i) ~ 0 from the appearance network keeps that dark. The full
  image is therefore asserted with a smaller margin.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch

from workers.models.lod.artifact import LodAsset, build_networks
from workers.models.lod.config import LodConfig
from workers.models.lod.evaluate import lod_tracer
from workers.models.lod.grid import LodGrid
from workers.models.lod.sampling import LodSource, LodSourceConfig, asset_tracer, asset_triangles
from workers.models.lod.thresholds import optimise_thresholds
from workers.models.lod.train import lod_loss
from workers.render.render import RenderSettings, render
from workers.runtime.samplers import InProcessBatches
from workers.runtime.sources import SourceSpec
from workers.runtime.training import train
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.reference import SceneRef

SEED = 0
STEPS = 120


def leak_config() -> LodConfig:
    small, mlp = {"features_per_level": 2}, {"width": 64, "depth": 2}
    return LodConfig(
        objects=["box"],
        finest_resolution=16,
        coarsest_resolution=8,
        appearance={"grid": {**small, "log2_table_size": 14}, "mlp": mlp},
        # a 2^8 table: hash collisions (see the module docstring)
        visibility={"grid": {**small, "log2_table_size": 8}, "mlp": mlp},
        sh_degree=4,
        batch_size=2048,
        train={"steps": STEPS, "schedule": {"lr": 0.005}, "checkpoint_every": STEPS, "progress_every": STEPS},
        threshold_samples=64,
        samplers=0,
    )


@contextlib.contextmanager
def one_torch_thread():
    """Small networks train as fast on one thread, and far faster when the 2 cores are busy (spinning
    OpenMP threads made a 3 s run take 50 s)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


def leaks(seed: int) -> dict[tuple[int, bool], float]:
    """Mean radiance of the inside view at LoD 0 per (max_depth, optimal thresholds)."""
    with one_torch_thread():
        return _leaks(seed)


def _leaks(seed: int) -> dict[tuple[int, bool], float]:
    config = leak_config()
    spec = get_builtin("closed_box")
    scene = compile_scene(spec)
    triangles = scene.positions[asset_triangles(scene, ["box"])].astype(np.float64)
    grid = LodGrid.build(triangles, config.resolutions)
    torch.manual_seed(seed)
    networks = build_networks(config, grid)
    source = LodSourceConfig(SceneRef(spec), ["box"], config, grid.arrays())
    train(networks, lod_loss, InProcessBatches(SourceSpec(LodSource, source, seed)), config.train)
    networks.eval()
    optimise_thresholds(
        grid, networks.visibility, asset_tracer(scene, ["box"]), config.threshold_samples,
        config.threshold_candidates, np.random.default_rng([seed, 1]),
    )  # fmt: skip
    asset = LodAsset(config, ["box"], grid, networks)
    out = {}
    for depth in (1, 8):
        settings = RenderSettings(spp=2, width=32, height=32, max_depth=depth, threads=1)
        for optimal in (True, False):
            image = render(lod_tracer(scene, asset, 0, optimal_thresholds=optimal), settings).image
            assert np.isfinite(image).all() and image.min() >= 0
            out[depth, optimal] = float(image.mean())
    return out


def test_closed_box_optimal_thresholds_leak_less_than_a_fixed_half():
    """Seeds 0-9 (mean radiance; the environment's is 4): camera rays through the walls (max_depth 1)
    optimal 0.12-0.51 vs fixed 0.45-1.50, ratio <= 0.44 (seed 0: 0.35 vs 1.07); full image optimal
    0.79-1.44 vs fixed 1.77-2.59, ratio <= 0.70 (seed 0: 1.25 vs 2.33)."""
    leak = leaks(SEED)
    primary_optimal, primary_fixed = leak[1, True], leak[1, False]
    assert primary_fixed > 0.25  # a fixed 0.5 does see through the walls: the test is not vacuous
    assert primary_optimal < 0.6 * primary_fixed, leak
    assert leak[8, True] < 0.85 * leak[8, False], leak
