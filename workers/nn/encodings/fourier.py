"""Sinusoidal encodings: NeRF positional encoding and mip-NeRF's integrated positional encoding."""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn


def octave_frequencies(n_frequencies: int, base: float = math.pi) -> list[float]:
    """NeRF's frequencies base * 2^k, k = 0..n_frequencies-1."""
    return [base * 2.0**k for k in range(n_frequencies)]


class _SinusoidalEncoding(nn.Module):
    def __init__(self, n_input_dims: int, frequencies: Sequence[float]) -> None:
        super().__init__()
        if not frequencies:
            raise ValueError("need at least one frequency")
        self.n_input_dims = n_input_dims
        self.register_buffer("frequencies", torch.tensor(list(frequencies), dtype=torch.float64))

    def _phases(self, x: Tensor) -> Tensor:
        """x [..., d] -> omega_k x_i [..., d * K], dimension-major."""
        return (x[..., :, None] * self.frequencies.to(x.dtype)).flatten(-2)


class FourierFeatures(_SinusoidalEncoding):
    """gamma(x) = [x, sin(omega_k x), cos(omega_k x)] per coordinate (Mildenhall et al. 2020)."""

    def __init__(self, n_input_dims: int, frequencies: Sequence[float], include_input: bool = True) -> None:
        super().__init__(n_input_dims, frequencies)
        self.include_input = include_input

    @property
    def n_output_dims(self) -> int:
        return self.n_input_dims * (2 * len(self.frequencies) + self.include_input)

    def forward(self, x: Tensor) -> Tensor:
        phases = self._phases(x)
        parts = [x] if self.include_input else []
        return torch.cat([*parts, torch.sin(phases), torch.cos(phases)], dim=-1)


class IntegratedPositionalEncoding(_SinusoidalEncoding):
    """Expected Fourier features of a Gaussian with diagonal covariance (Barron et al. 2021, mip-NeRF).

    E[sin(w x)] = sin(w mu) exp(-w^2 var / 2), likewise for cos: frequencies finer than the Gaussian's
    footprint fade out instead of aliasing.
    """

    @property
    def n_output_dims(self) -> int:
        return self.n_input_dims * 2 * len(self.frequencies)

    def forward(self, mean: Tensor, variance: Tensor) -> Tensor:
        """mean, variance [..., d] (variance >= 0, negatives clamped) -> [..., 2 d K]."""
        phases = self._phases(mean)
        frequencies = self.frequencies.to(mean.dtype)
        attenuation = torch.exp(-0.5 * (variance.clamp(min=0.0)[..., :, None] * frequencies**2).flatten(-2))
        return torch.cat([torch.sin(phases) * attenuation, torch.cos(phases) * attenuation], dim=-1)
