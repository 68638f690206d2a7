"""The two networks of a prefiltered asset (Weier et al. 2023, Sec. 4.2-4.3), trained together.

Appearance: SH of w_o and w_i plus a hash grid of the voxel centre -> MLP -> RGB average throughput
phi_V(w_o, w_i) (Eq. 3), linear or exponentiated. Visibility: both voxel-boundary points through one shared
hash grid (recurrent composite encoding) -> MLP -> logit of "the segment is unoccluded".
Both hash grids have one level per octave from the coarsest LoD's resolution to the finest's (one per LoD
when all are built, as in the paper), scale 2.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from workers.models.lod.config import LodConfig
from workers.nn.encodings.composite import SharedInputsEncoding
from workers.nn.encodings.spherical_harmonics import SphericalHarmonics

# Energy conservation bounds the integral of phi over w_i by the voxel's albedo (<= 1), so its mean over
# uniform w_i, the training distribution, is at most 1/(4 pi); a mid-grey asset's is about 0.5/(4 pi).
PRIOR_THROUGHPUT = 0.5 / (4 * math.pi)
# exp() of the log output stays above 0 (a relative loss divides by it) and far below anything visible...
MIN_LOG_THROUGHPUT = math.log(1e-6)
MAX_LOG_THROUGHPUT = 20.0  # ... and far below infinity, above any physical throughput


class AppearanceNetwork(nn.Module):
    """phi = the MLP's output (linear) or its exp (log). The last bias starts at the prior mean (its log),
    so the log output starts near the targets, not at exp(0) = 1, 20x above them. The log output is clamped
    to [MIN_LOG_THROUGHPUT, MAX_LOG_THROUGHPUT] in value only: the gradient passes the clamp (straight
    through), so an output pushed below the floor is still pulled back up by its non-zero targets
    (`train.positive_relative_l2` says why that pull never fades)."""

    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        self.log_output = config.appearance_output == "log"
        self.directions = SphericalHarmonics(config.sh_degree)
        size = config.appearance
        self.position = size.grid.build_on(size.lattice(octaves, coarsest))
        n_in = 2 * self.directions.n_output_dims + self.position.n_output_dims
        self.mlp = size.mlp.build(n_in, 3)
        output_layer = self.mlp.layers[-2]  # the last Linear (the output activation is the identity)
        nn.init.constant_(
            output_layer.bias, math.log(PRIOR_THROUGHPUT) if self.log_output else PRIOR_THROUGHPUT
        )

    def forward(self, centre: Tensor, wo: Tensor, wi: Tensor) -> Tensor:
        """phi (N, 3) for voxel centres in cube coordinates and unit directions (N, 3)."""
        features = torch.cat([self.position(centre), self.directions(wo), self.directions(wi)], dim=-1)
        raw = self.mlp(features)
        if not self.log_output:
            return raw
        bounded = raw + (raw.clamp(MIN_LOG_THROUGHPUT, MAX_LOG_THROUGHPUT) - raw).detach()
        return torch.exp(bounded)


class VisibilityNetwork(nn.Module):
    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        size = config.visibility
        self.points = SharedInputsEncoding(size.grid.build_on(size.lattice(octaves, coarsest)), n_inputs=2)
        self.mlp = size.mlp.build(self.points.n_output_dims, 1)

    def forward(self, p_o: Tensor, p_i: Tensor) -> Tensor:
        """Logits (N,) that the segments between boundary points (cube coordinates) are unoccluded."""
        return self.mlp(self.points(torch.cat([p_o, p_i], dim=-1)))[:, 0]


class LodNetworks(nn.Module):
    """Both networks of one asset; one module so one optimiser and one checkpoint hold them."""

    def __init__(self, config: LodConfig, octaves: int, coarsest: int) -> None:
        super().__init__()
        self.appearance = AppearanceNetwork(config, octaves, coarsest)
        self.visibility = VisibilityNetwork(config, octaves, coarsest)
