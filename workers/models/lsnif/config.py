"""The `lsnif` kind's config and presets: the paper's sizes (`paper`) and sizes this 2-core CPU trains.

The defaults are the paper's network (Sec. 5.1): V = 32 voxels, H = 18 points, two grid levels 64^3 to
128^3 with 3 features and a 2^17-entry table, two hidden layers of 128. The presets change the batch and
the number of steps (and, for `quick`, the sizes), not the method.
"""

from __future__ import annotations

from pydantic import Field

from workers.nn.configs import HashGridConfig, MLPConfig
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import Schedule, TrainConfig


class LsnifConfig(TrainedKindConfig):
    # Objects train one after another on batches made in the driver by default (measured no slower at
    # the default batch than one sampler actor on this 2-core CPU, which the driver's training shares).
    samplers: int = Field(0, ge=0, le=1024, description="Ray actors generating training batches")

    voxel_resolution: int = Field(32, ge=1, le=256, description="V: voxels per side of an object's box")
    max_points: int = Field(18, ge=1, le=256, description="H: boundary points per ray fed to the MLP")
    # The sparse grid's lattice and table (M = 2^log2_table_size rows per level, folded beyond; see
    # `encoding`) and the MLP that reads the H points' concatenated features.
    grid: HashGridConfig = HashGridConfig(
        levels=2, features_per_level=3, log2_table_size=17, base_resolution=64, per_level_scale=2.0
    )
    mlp: MLPConfig = MLPConfig(width=128, depth=2, activation="leaky_relu")
    batch_size: int = Field(
        1 << 13, ge=64, le=1 << 22, description="rays drawn per step; those meeting no voxel are dropped"
    )
    # 8M rays: held-out occlusion accuracy on high_poly went from 97.0% at 150 steps to 98.9% at 1000
    # (normal error 33 -> 17 degrees), about two and a half minutes on an idle 2-core CPU.
    train: TrainConfig = TrainConfig(
        steps=1000, schedule=Schedule(lr=0.01), checkpoint_every=250, progress_every=10
    )
    min_triangles: int = Field(
        5000, ge=0, description="objects with fewer triangles stay on Embree (LSNIF pays off on complex ones)"
    )
    evaluation_rays: int = Field(
        1 << 15, ge=256, le=1 << 22, description="held-out rays per object for the report"
    )
    preview_size: int = Field(96, ge=8, le=2048, description="side of the report's comparison image")


PRESETS: dict[str, dict] = {
    # `quick` trains models measurably better than trivial (the integration test's gates): on the
    # instanced ball, held-out occlusion in voxels 0.78 / 0.83 / 0.97 at 30 / 60 / 150 steps against 0.78
    # for "always miss", normal error 44 -> 24 degrees from 60 to 150 steps (seeds 0, 3, 7 alike).
    "quick": {
        "voxel_resolution": 16,
        "max_points": 12,
        "grid": {"base_resolution": 32, "log2_table_size": 14},
        "mlp": {"width": 64},
        "batch_size": 2048,
        "train": {"steps": 150, "schedule": {"lr": 0.01}, "checkpoint_every": 50, "progress_every": 10},
        "evaluation_rays": 4096,
        "preview_size": 32,
        "evaluation_spp": 4,
        "reference_spp": 256,
    },
    "default": {},
    "paper": {
        "batch_size": 1 << 18,
        "train": {"steps": 2000, "schedule": {"lr": 0.01}, "checkpoint_every": 250, "progress_every": 20},
        "evaluation_rays": 1 << 18,
        "preview_size": 512,
        "evaluation_spp": 256,
        "reference_spp": 2048,
        "num_gpus": 1,
    },
}
