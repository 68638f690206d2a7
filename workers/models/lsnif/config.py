"""The `lsnif` kind's config (Fujieda et al., I3D 2025, "LSNIF: Locally-Subdivided Neural
Intersection Function") and its presets (`presets/*.yaml`).

The defaults are the paper's network (Sec. 5.1): V = 32 voxels, H = 18 points, two grid levels 64^3 to
128^3 with 3 features and a 2^17-entry table, two hidden layers of 128. The presets change the batch and
the number of steps (and, for `quick`, the sizes), not the method.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from pydantic import Field

from workers.nn.configs import HashGridConfig, MLPConfig
from workers.runtime.kind_config import TrainedKindConfig, results_link
from workers.runtime.presets import load_presets
from workers.runtime.training import Schedule, TrainConfig

evidence = partial(results_link, "lsnif")


class LsnifConfig(TrainedKindConfig):
    """The neural intersection function's knobs: its voxels and points per ray, the sparse grid and MLP,
    and which objects it replaces."""

    samplers: int = Field(
        0,
        ge=0,
        le=1024,
        description="Ray actors generating training batches; 0 makes them in the driver, no slower at the "
        f"default batch than one actor on a 2-core CPU {evidence('samplers')}.",
    )
    voxel_resolution: int = Field(32, ge=1, le=256, description="V: voxels per side of an object's box.")
    max_points: int = Field(18, ge=1, le=256, description="H: boundary points per ray fed to the MLP.")
    grid: HashGridConfig = Field(
        HashGridConfig(
            levels=2, features_per_level=3, log2_table_size=17, base_resolution=64, per_level_scale=2.0
        ),
        description="The sparse grid's lattice and table (2^log2_table_size rows a level, folded beyond).",
    )
    mlp: MLPConfig = Field(
        MLPConfig(width=128, depth=2, activation="leaky_relu"),
        description="The MLP reading the H points' concatenated features.",
    )
    batch_size: int = Field(
        1 << 13, ge=64, le=1 << 22, description="Rays drawn per step; those meeting no voxel are dropped."
    )
    train: TrainConfig = Field(
        TrainConfig(steps=1000, schedule=Schedule(lr=0.01), checkpoint_every=250, progress_every=10),
        description="The training loop: 1000 steps of 8192 rays took held-out occlusion accuracy from 97.0% "
        f"to 98.9% in about two and a half minutes {evidence('steps')}.",
    )
    min_triangles: int = Field(
        5000,
        ge=0,
        description="Objects with fewer triangles stay on Embree: LSNIF pays off on complex ones.",
    )
    evaluation_rays: int = Field(
        1 << 15, ge=256, le=1 << 22, description="Held-out rays per object for the report."
    )
    preview_size: int = Field(96, ge=8, le=2048, description="Side of the report's comparison image.")


PRESETS = load_presets(LsnifConfig, Path(__file__).with_name("presets"))
