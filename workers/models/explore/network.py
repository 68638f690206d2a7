"""The pixel generator with position preconditioning (thesis Sec. 5.3.2, App. A.5, Table 5.5).

Position alone goes through the first layer; each of the `depth` hidden layers then reads its input
concatenated with the raw buffers and v again (skip connections at every layer); a linear layer gives
log1p of the radiance leaving the first hit. Pixels are independent, so a network trained on patches
renders any resolution. Emission is passed through [code]: where log1p(E) > 1 the output is E itself,
elsewhere the prediction plus log1p(E).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from workers.models.explore.features import BUFFER_CHANNELS, POSITION
from workers.nn.configs import MLPConfig
from workers.nn.mlp import make_activation

BRIGHT_EMITTER = 1.0  # log1p radiance above which an emitter's pixel is its emission alone [code]


class PixelGenerator(nn.Module):
    def __init__(self, dimensions: int, mlp: MLPConfig) -> None:
        super().__init__()
        self.dimensions = dimensions
        inputs = BUFFER_CHANNELS + dimensions
        self.first = nn.Linear(3, mlp.width)
        self.hidden = nn.ModuleList(nn.Linear(mlp.width + inputs, mlp.width) for _ in range(mlp.depth))
        self.output = nn.Linear(mlp.width, 3)
        self.activation = make_activation(mlp.activation)

    def forward(self, features: Tensor, emission: Tensor) -> Tensor:
        """log1p radiance [..., 3] of pixels with `features` [..., 13 + K] and first-hit `emission`."""
        h = self.activation(self.first(features[..., POSITION]))
        for layer in self.hidden:
            h = self.activation(layer(torch.cat([h, features], dim=-1)))
        emitted = torch.log1p(emission)
        passthrough = (emitted > BRIGHT_EMITTER).any(dim=-1, keepdim=True)
        return torch.where(passthrough, emitted, self.output(h) + emitted)

    @torch.no_grad()
    def radiance(self, features: Tensor, emission: Tensor) -> Tensor:
        """Linear radiance, clamped at zero."""
        return torch.expm1(self(features, emission)).clamp_min(0.0)
