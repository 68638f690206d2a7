"""The two networks of a prefiltered asset (Weier et al. 2023, Sec. 4.2-4.3), trained together.

Appearance: SH of w_o and w_i plus a hash grid of the voxel centre -> MLP -> RGB average throughput
phi_V(w_o, w_i) (Eq. 3), linear or exponentiated. Visibility: both voxel-boundary points through one shared
hash grid (recurrent composite encoding) -> MLP -> logit of "the segment is unoccluded".
Both hash grids have one level per octave from the coarsest LoD's resolution to the finest's (one per LoD
when all are built, as in the paper), scale 2.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from workers.models.lod.config import LodConfig, NetworkSize
from workers.nn.encodings.composite import SharedInputsEncoding
from workers.nn.encodings.hashgrid import HashGrid
from workers.nn.encodings.spherical_harmonics import SphericalHarmonics
from workers.nn.mlp import MLP

MAX_LOG_THROUGHPUT = 20.0  # exp() of the log output is capped far above any physical throughput


def _hash_grid(size: NetworkSize, octaves: int, coarsest: int) -> HashGrid:
    return HashGrid(
        n_input_dims=3,
        n_levels=octaves + size.extra_levels,
        n_features_per_level=size.features_per_level,
        log2_hashmap_size=size.log2_table_size,
        base_resolution=coarsest,
        per_level_scale=2.0,
    )


class AppearanceNetwork(nn.Module):
    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        self.log_output = config.appearance_output == "log"
        self.directions = SphericalHarmonics(config.sh_degree)
        self.position = _hash_grid(config.appearance, octaves, coarsest)
        size = config.appearance
        n_in = 2 * self.directions.n_output_dims + self.position.n_output_dims
        self.mlp = MLP(n_in, 3, size.width, size.depth, activation="relu")

    def forward(self, centre: Tensor, wo: Tensor, wi: Tensor) -> Tensor:
        """phi (N, 3) for voxel centres in cube coordinates and unit directions (N, 3)."""
        features = torch.cat([self.position(centre), self.directions(wo), self.directions(wi)], dim=-1)
        raw = self.mlp(features)
        return torch.exp(raw.clamp(max=MAX_LOG_THROUGHPUT)) if self.log_output else raw


class VisibilityNetwork(nn.Module):
    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        self.points = SharedInputsEncoding(_hash_grid(config.visibility, octaves, coarsest), n_inputs=2)
        size = config.visibility
        self.mlp = MLP(self.points.n_output_dims, 1, size.width, size.depth, activation="relu")

    def forward(self, p_o: Tensor, p_i: Tensor) -> Tensor:
        """Logits (N,) that the segments between boundary points (cube coordinates) are unoccluded."""
        return self.mlp(self.points(torch.cat([p_o, p_i], dim=-1)))[:, 0]


class LodNetworks(nn.Module):
    """Both networks of one asset; one module so one optimiser and one checkpoint hold them."""

    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        self.appearance = AppearanceNetwork(config, octaves, coarsest)
        self.visibility = VisibilityNetwork(config, octaves, coarsest)
