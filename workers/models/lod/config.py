"""The `lod` kind's config and presets: the paper's sizes (`paper`) and sizes this 2-core CPU trains.

`paper` is Weier et al. 2023: LoD 0 at 512^3 down to 8^3, hash tables of 2^19 rows, two 4x128 MLPs,
1000 threshold samples per voxel, Adam at 0.005. `default` (64^3 down to 8^3, tables of 2^17, 128
threshold samples: about five minutes on an idle 2-core CPU) and `quick` shrink the finest level, the
tables and the step count, not the method.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from workers.nn.configs import HashTableConfig, MLPConfig
from workers.nn.encodings.grid import GridGeometry
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import Schedule, TrainConfig
from workers.scene.format.strict import StrictModel


class NetworkConfig(StrictModel):
    """One of the asset's networks: a hash table on the lattice the LoDs derive (one level per octave from
    the coarsest LoD's resolution, scale 2, plus `extra_levels` finer than LoD 0) and a ReLU MLP."""

    grid: HashTableConfig = HashTableConfig(features_per_level=4, log2_table_size=19)
    mlp: MLPConfig = MLPConfig(width=128, depth=4)
    extra_levels: int = Field(
        0, ge=0, le=2, description="hash-grid levels finer than LoD 0 (resolution doubling each)"
    )

    def lattice(self, octaves: int, coarsest: int) -> GridGeometry:
        return GridGeometry(3, octaves + self.extra_levels, coarsest, 2.0)


def _power_of_two(value: int) -> int:
    if value & (value - 1):
        raise ValueError(f"must be a power of two, got {value}")
    return value


class LodConfig(TrainedKindConfig):
    objects: list[str] | None = Field(
        None, description="names of the objects to prefilter; default: non-emitting objects >= min_triangles"
    )
    min_triangles: int = Field(1000, ge=0)
    finest_resolution: int = Field(64, ge=16, le=1024, description="voxels per side at LoD 0 (power of 2)")
    coarsest_resolution: int = Field(8, ge=1, le=512, description="voxels per side at the coarsest LoD")
    view_distances: list[float] = Field(
        [],
        max_length=64,
        description="camera distances the asset will be seen from (scene camera's fov and width); the plan "
        "builds only the LoDs whose voxels match a pixel at one of them. Empty: every LoD.",
    )
    appearance: NetworkConfig = NetworkConfig()
    visibility: NetworkConfig = NetworkConfig()
    sh_degree: int = Field(8, ge=1, le=8)
    # The paper learns phi directly, its reference code in log space. Log once trained to black (FLIP
    # ~0.95: any asset, seed-dependent) until its start and loss were fixed (`AppearanceNetwork`,
    # `positive_relative_l2`). After the fix, FLIP per LoD (32^3, 16^3, 8^3; default preset at 32^3, 500
    # steps, 64 threshold samples, 16 spp against 256), linear -> log, seeds 0 and 1 where two:
    #   Menger L3   0.149 0.111 0.101, 0.142 0.110 0.127 -> 0.180 0.140 0.120, 0.135 0.114 0.132
    #   blob 0.5    0.101 0.083 0.089 -> 0.096 0.080 0.072
    #   blob 0.15   0.180 0.147 0.144, 0.156 0.141 0.133 -> 0.110 0.110 0.111, 0.132 0.118 0.095
    #   blob 0.03   0.319 0.275 0.249 -> 0.103 0.088 0.117
    #   blob glossy 0.214 0.194 0.138 -> 0.184 0.141 0.158
    # (blob: a closed smooth 56k-triangle displaced sphere of that albedo, or glossy plastic.) LoD 0's
    # relative MSE: equal on the sponge, 0.024 -> 0.027 on blob 0.5, lower with log on the others (0.010 ->
    # 0.005 on blob 0.03). Log is as good on the bright sponge within seed noise and far better on dark
    # assets (a linear output's relative L2 turns absolute below 0.1, above every throughput): the default.
    appearance_output: Literal["linear", "log"] = Field(
        "log", description="log: phi = exp(output) (always positive); linear: phi = network output"
    )
    batch_size: int = Field(
        1 << 13, ge=64, le=1 << 22, description="voxel samples per step (pairs of boundary points)"
    )
    domain_extrusion: float = Field(0.005, ge=0, le=0.1, description="learned domain grown by this x voxel")
    max_voxel_bounces: int = Field(64, ge=1, le=1024, description="cap on a training path inside a voxel")
    train: TrainConfig = TrainConfig(
        steps=1500, schedule=Schedule(lr=0.005), checkpoint_every=250, progress_every=10
    )
    threshold_samples: int = Field(1000, ge=16, le=100_000, description="fresh visibility samples per voxel")
    threshold_candidates: int = Field(100, ge=2, le=10_000)
    stochastic_traversal: bool = True
    survival_floor_at_512: float = Field(
        0.9925, gt=0, le=1, description="lowest survival per voxel at 512^3; scaled to keep the diagonal's"
    )
    evaluation_spp: int = Field(64, ge=1, le=65536, description="spp of each LoD's frames")
    reference_spp: int = Field(512, ge=2, le=1 << 20, description="spp of the converged path-traced images")
    evaluation_max_height: int = Field(
        192, ge=8, le=4096, description="cap on the height of the images that measure each LoD"
    )

    _power_of_two = field_validator("finest_resolution", "coarsest_resolution")(_power_of_two)

    @model_validator(mode="after")
    def _levels(self) -> LodConfig:
        if self.coarsest_resolution > self.finest_resolution:
            raise ValueError(
                f"coarsest_resolution ({self.coarsest_resolution}) must not exceed finest_resolution "
                f"({self.finest_resolution})"
            )
        return self

    @property
    def resolutions(self) -> list[int]:
        """Voxels per side of every LoD the config allows, LoD 0 (finest) first."""
        out, r = [], self.finest_resolution
        while r >= self.coarsest_resolution:
            out.append(r)
            r //= 2
        return out


PRESETS: dict[str, dict] = {
    # `quick` trains models measurably better than trivial (the integration test's gates). On the Menger
    # sponge at 48x48, seeds 0, 3 and 5, FLIP per LoD / the asset's mean radiance over path tracing's:
    # 20 x 2048 samples 0.51 0.44 0.37 / 0.47-0.61 (seed 3); 60 x 2048 0.39 0.31 0.24 / 0.69-0.85 (seed 3);
    # 150 x 2048 0.25-0.31 / 0.78-1.36; 100 x 4096 0.16-0.29 / 0.86-1.17, as good as 200 x 2048 and
    # cheaper: a step's cost is mostly per-operation overhead at these sizes.
    "quick": {
        "finest_resolution": 32,
        "appearance": {
            "grid": {"features_per_level": 2, "log2_table_size": 14},
            "mlp": {"width": 64, "depth": 2},
        },
        "visibility": {
            "grid": {"features_per_level": 2, "log2_table_size": 14},
            "mlp": {"width": 64, "depth": 2},
        },
        "sh_degree": 4,
        "batch_size": 4096,
        "train": {"steps": 100, "schedule": {"lr": 0.005}, "checkpoint_every": 50, "progress_every": 10},
        "threshold_samples": 64,
        "evaluation_spp": 4,
        "reference_spp": 16,
        "evaluation_max_height": 48,
    },
    "default": {
        "appearance": {"grid": {"features_per_level": 4, "log2_table_size": 17}},
        "visibility": {"grid": {"features_per_level": 4, "log2_table_size": 17}},
        "threshold_samples": 128,
    },
    "paper": {
        "finest_resolution": 512,
        "appearance": {"grid": {"features_per_level": 4, "log2_table_size": 19}},
        "visibility": {"grid": {"features_per_level": 8, "log2_table_size": 19}},
        "batch_size": 1 << 16,
        "train": {"steps": 10000, "schedule": {"lr": 0.005}, "checkpoint_every": 500, "progress_every": 50},
        "threshold_samples": 1000,
        "evaluation_spp": 1024,
        "reference_spp": 4096,
        "evaluation_max_height": 512,
        "samplers": 4,
        "num_gpus": 1,
    },
}
