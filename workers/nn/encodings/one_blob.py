"""One-blob encoding (Müller et al. 2019, neural importance sampling): a soft one-hot of a scalar."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn


class OneBlob(nn.Module):
    """Each coordinate in [0, 1] becomes n_bins values: the mass a Gaussian of std 1/n_bins centred on it
    puts in each of n_bins equal bins (a differentiable soft one-hot; dimension-major output)."""

    def __init__(self, n_input_dims: int, n_bins: int = 32) -> None:
        super().__init__()
        if n_bins < 2:
            raise ValueError(f"n_bins must be at least 2, got {n_bins}")
        self.n_input_dims = n_input_dims
        self.n_bins = n_bins
        self.register_buffer("edges", torch.linspace(0.0, 1.0, n_bins + 1))

    @property
    def n_output_dims(self) -> int:
        return self.n_input_dims * self.n_bins

    def forward(self, x: Tensor) -> Tensor:
        scaled = (self.edges.to(x.dtype) - x[..., :, None]) * (self.n_bins / math.sqrt(2.0))
        cdf = 0.5 * torch.erf(scaled)
        return (cdf[..., 1:] - cdf[..., :-1]).flatten(-2)
