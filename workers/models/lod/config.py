"""The `lod` kind's config (Weier et al. 2023, "Neural Prefiltering for Correlation-Aware Levels of
Detail") and its presets (`presets/*.yaml`): the paper's sizes (`paper`) and sizes a 2-core CPU trains
(`default`, `quick`), which shrink the finest level, the tables and the step count, not the method.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator, model_validator

from workers.nn.configs import HashTableConfig, MLPConfig
from workers.nn.encodings.grid import GridGeometry
from workers.runtime.kind_config import TrainedKindConfig, results_link
from workers.runtime.presets import load_presets
from workers.runtime.training import Schedule, TrainConfig
from workers.scene.format.strict import StrictModel

evidence = partial(results_link, "lod")


class NetworkConfig(StrictModel):
    """One of the asset's networks: a hash table on the lattice the LoDs derive (one level per octave from
    the coarsest LoD's resolution, scale 2, plus `extra_levels` finer than LoD 0) and a ReLU MLP."""

    grid: HashTableConfig = Field(
        HashTableConfig(features_per_level=4, log2_table_size=19),
        description="The network's hash table; its lattice is derived from the LoDs.",
    )
    mlp: MLPConfig = Field(MLPConfig(width=128, depth=4), description="The ReLU MLP reading the grid.")
    extra_levels: int = Field(
        0, ge=0, le=2, description="Hash-grid levels finer than LoD 0 (resolution doubling each)."
    )

    def lattice(self, octaves: int, coarsest: int) -> GridGeometry:
        return GridGeometry(3, octaves + self.extra_levels, coarsest, 2.0)


def _power_of_two(value: int) -> int:
    if value & (value - 1):
        raise ValueError(f"must be a power of two, got {value}")
    return value


class LodConfig(TrainedKindConfig):
    """Neural prefiltering's knobs: which objects, the LoDs' resolutions, the appearance and visibility
    networks, their training and the thresholds that make visibility binary."""

    objects: list[str] | None = Field(
        None,
        description="Names of the objects to prefilter; null: every non-emitting object of at least "
        "`min_triangles` triangles.",
    )
    min_triangles: int = Field(
        1000, ge=0, description="Objects with fewer triangles stay meshes when `objects` is null."
    )
    finest_resolution: int = Field(
        64, ge=16, le=1024, description="Voxels per side at LoD 0 (a power of two)."
    )
    coarsest_resolution: int = Field(
        8, ge=1, le=512, description="Voxels per side at the coarsest LoD (a power of two)."
    )
    view_distances: list[float] = Field(
        [],
        max_length=64,
        description="Camera distances the asset will be seen from (with the scene camera's fov and width); "
        "the plan builds only the LoDs whose voxels match a pixel at one of them. Empty: every LoD.",
    )
    appearance: NetworkConfig = Field(
        NetworkConfig(), description="The network of the voxels' appearance (phi and its SH lobes)."
    )
    visibility: NetworkConfig = Field(
        NetworkConfig(), description="The network of the probability that a ray crosses a voxel."
    )
    sh_degree: int = Field(
        8, ge=1, le=8, description="Spherical-harmonics degree of the appearance's directional lobes."
    )
    appearance_output: Literal["linear", "log"] = Field(
        "log",
        description="log: phi = exp(output), always positive; linear: phi = the network's output. Log is "
        f"as good on bright assets and far better on dark ones {evidence('appearance-output')}.",
    )
    batch_size: int = Field(
        1 << 13, ge=64, le=1 << 22, description="Voxel samples per step (pairs of boundary points)."
    )
    domain_extrusion: float = Field(
        0.005, ge=0, le=0.1, description="The learned domain is grown by this fraction of a voxel."
    )
    max_voxel_bounces: int = Field(
        64, ge=1, le=1024, description="Cap on a training path's bounces inside a voxel."
    )
    train: TrainConfig = Field(
        TrainConfig(steps=1500, schedule=Schedule(lr=0.005), checkpoint_every=250, progress_every=10),
        description="The training loop; Adam at 0.005 as in the paper.",
    )
    threshold_samples: int = Field(
        1000, ge=16, le=100_000, description="Fresh visibility samples per voxel for its threshold."
    )
    threshold_candidates: int = Field(
        100, ge=2, le=10_000, description="Thresholds in [0, 1] a grid search tries per voxel."
    )
    stochastic_traversal: bool = Field(
        True,
        description="A ray passing a voxel survives with probability max(p, floor) and is reweighted, so "
        "long walks through nearly empty voxels end early without bias (Sec. 4.5).",
    )
    survival_floor_at_512: float = Field(
        0.9925,
        gt=0,
        le=1,
        description="Lowest survival per voxel at 512^3; scaled at other resolutions to keep the diagonal's.",
    )
    evaluation_spp: int = Field(64, ge=1, le=65536, description="Samples per pixel of each LoD's frames.")
    reference_spp: int = Field(
        512, ge=2, le=1 << 20, description="Samples per pixel of the converged path-traced images."
    )
    evaluation_max_height: int = Field(
        192, ge=8, le=4096, description="Cap on the height of the images that measure each LoD."
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


PRESETS = load_presets(LodConfig, Path(__file__).with_name("presets"))
