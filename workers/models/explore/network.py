"""The pixel generator with position preconditioning (thesis Sec. 5.3.2, App. A.5, Table 5.5).

Position alone goes through the first layer; each of the `depth` hidden layers then reads its input
concatenated with the raw buffers and v again (skip connections at every layer); a linear layer gives
log1p of the radiance leaving the first hit. Pixels are independent, so a network trained on patches
renders any resolution. Emission is passed through [code]: where log1p(E) > 1 the output is E itself,
elsewhere the prediction plus log1p(E). A pixel whose ray escaped is its emission alone, the environment's
exact radiance (`gbuffer.primary_gbuffers`): the network neither learns the background nor trains on it.

Optionally the first layer also reads a multiresolution hash grid of the normalised position (instant-ngp;
not in the thesis, whose 8 x 512 network trains for ~2 x 10^5 steps): what does not vary with v is
stored in the grid's table and learned in far fewer steps, so minutes of CPU training leave the
configuration-dependent error standing out. It is still a function of position alone, so the
preconditioning keeps its meaning.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from workers.models.explore.config import ExploreConfig
from workers.models.explore.features import BUFFER_CHANNELS, NORMAL, POSITION
from workers.nn.configs import HashGridConfig, MLPConfig
from workers.nn.mlp import make_activation

BRIGHT_EMITTER = 1.0  # log1p radiance above which an emitter's pixel is its emission alone [code]


def escaped(features: Tensor) -> Tensor:
    """[..., 1] bool: the pixels whose ray escaped, whose buffers `pixel_features` left all zero."""
    return (features[..., NORMAL] == 0).all(dim=-1, keepdim=True)


class PixelGenerator(nn.Module):
    def __init__(self, dimensions: int, mlp: MLPConfig, position_grid: HashGridConfig | None = None) -> None:
        super().__init__()
        self.dimensions = dimensions
        inputs = BUFFER_CHANNELS + dimensions
        self.grid = position_grid.build(3) if position_grid is not None else None
        encoded = 3 + (self.grid.n_output_dims if self.grid is not None else 0)
        self.first = nn.Linear(encoded, mlp.width)
        self.hidden = nn.ModuleList(nn.Linear(mlp.width + inputs, mlp.width) for _ in range(mlp.depth))
        self.output = nn.Linear(mlp.width, 3)
        self.activation = make_activation(mlp.activation)

    @classmethod
    def of(cls, config: ExploreConfig, dimensions: int) -> PixelGenerator:
        """The network a config describes, for a scene of `dimensions` variables."""
        return cls(dimensions, config.mlp, config.position_grid)

    def encode_position(self, position: Tensor) -> Tensor:
        """The first layer's input: the normalised position [..., 3], then its grid features if any."""
        if self.grid is None:
            return position
        return torch.cat([position, self.grid(position)], dim=-1)

    def forward(self, features: Tensor, emission: Tensor, encoded: Tensor | None = None) -> Tensor:
        """log1p radiance [..., 3] of pixels with `features` [..., 13 + K] and `emission` (first hit's, or
        the environment's for escaped rays);
        `encoded`: the first layer's input if already computed (`encode_position`), e.g. held constant."""
        if encoded is None:
            encoded = self.encode_position(features[..., POSITION])
        h = self.activation(self.first(encoded))
        for layer in self.hidden:
            h = self.activation(layer(torch.cat([h, features], dim=-1)))
        emitted = torch.log1p(emission)
        passthrough = (emitted > BRIGHT_EMITTER).any(dim=-1, keepdim=True) | escaped(features)
        return torch.where(passthrough, emitted, self.output(h) + emitted)

    def layers(self) -> dict[str, nn.Parameter]:
        """The layers' parameters by name: everything but the grid's table."""
        return {name: p for name, p in self.named_parameters() if not name.startswith("grid.")}

    def parameter_groups(self, grid_lr_scale: float) -> list[dict]:
        """Adam groups: the layers at the scheduled rate, the grid's table at `grid_lr_scale` times it."""
        layers = list(self.layers().values())
        if self.grid is None:
            return [{"params": layers}]
        return [{"params": layers}, {"params": list(self.grid.parameters()), "lr_scale": grid_lr_scale}]

    @torch.no_grad()
    def radiance(self, features: Tensor, emission: Tensor) -> Tensor:
        """Linear radiance, clamped at zero."""
        return torch.expm1(self(features, emission)).clamp_min(0.0)
