"""Haar wavelets on cube maps (Ng, Ramamoorthi and Hanrahan 2003) for all-frequency PRT lighting.

Each face is decomposed with the non-standard 2D Haar transform, orthonormal, in the usual in-place
layout: after each step the top-left quadrant holds the averages and is decomposed again; the other three
quadrants hold the horizontal, vertical and diagonal details. Coefficient (face, row, col) of a cube
[6, S, S, C] is the wavelet index k; flat index = (face * S + row) * S + col.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor


def _check_square_power_of_two(x: Tensor) -> int:
    size = x.shape[-1]
    if x.shape[-2] != size or size < 1 or size & (size - 1):
        raise ValueError(f"Haar transform needs square power-of-two images, got {tuple(x.shape[-2:])}")
    return size


def haar2d(x: Tensor) -> Tensor:
    """Non-standard orthonormal 2D Haar decomposition of images [..., S, S]."""
    out = x.clone()
    n = _check_square_power_of_two(x)
    while n > 1:
        h = n // 2
        block = out[..., :n, :n]
        a, b = block[..., 0::2, 0::2], block[..., 0::2, 1::2]
        c, d = block[..., 1::2, 0::2], block[..., 1::2, 1::2]
        top = torch.cat(((a + b + c + d) / 2, (a - b + c - d) / 2), dim=-1)
        bottom = torch.cat(((a + b - c - d) / 2, (a - b - c + d) / 2), dim=-1)
        out[..., :n, :n] = torch.cat((top, bottom), dim=-2)
        n = h
    return out


def inverse_haar2d(coefficients: Tensor) -> Tensor:
    """Exact inverse of `haar2d` (the 2x2 step is symmetric and orthonormal, so it is its own inverse)."""
    out = coefficients.clone()
    size = _check_square_power_of_two(coefficients)
    n = 2
    while n <= size:
        h = n // 2
        average, horizontal = out[..., :h, :h], out[..., :h, h:n]
        vertical, diagonal = out[..., h:n, :h], out[..., h:n, h:n]
        a = (average + horizontal + vertical + diagonal) / 2
        b = (average - horizontal + vertical - diagonal) / 2
        c = (average + horizontal - vertical - diagonal) / 2
        d = (average - horizontal - vertical + diagonal) / 2
        block = torch.empty_like(out[..., :n, :n])
        block[..., 0::2, 0::2], block[..., 0::2, 1::2] = a, b
        block[..., 1::2, 0::2], block[..., 1::2, 1::2] = c, d
        out[..., :n, :n] = block
        n *= 2
    return out


def cubemap_wavelets(cube: Tensor) -> Tensor:
    """Per-face, per-channel Haar coefficients of a cube map [6, S, S, C], same layout."""
    return haar2d(cube.movedim(-1, 0)).movedim(0, -1)


def cubemap_from_wavelets(coefficients: Tensor) -> Tensor:
    """The cube map [6, S, S, C] whose `cubemap_wavelets` are `coefficients`."""
    return inverse_haar2d(coefficients.movedim(-1, 0)).movedim(0, -1)


def support_fraction(size: int, dtype: torch.dtype = torch.float32) -> Tensor:
    """Fraction [S, S] of its face that each coefficient's basis function covers (1 for the scaling
    function and the coarsest details, 1/4 one level finer, ...)."""
    index = torch.arange(size)
    level_extent = torch.maximum(index[:, None], index[None, :])
    # Details at rows/cols in [b, 2b) have blocks of S/b texels; the scaling coefficient covers the face.
    block = torch.where(
        level_extent > 0, 2 ** torch.floor(torch.log2(level_extent.clamp(min=1).double())), 1.0
    )
    return (1.0 / block**2).to(dtype)


@dataclass(frozen=True)
class SparseWavelets:
    """K selected cube-map wavelet coefficients: flat `indices` [K] and their `values` [K, C]."""

    indices: Tensor
    values: Tensor
    size: int

    def dense(self) -> Tensor:
        """All coefficients [6, S, S, C], zero where not selected."""
        out = self.values.new_zeros(6 * self.size * self.size, self.values.shape[-1])
        out[self.indices] = self.values
        return out.view(6, self.size, self.size, -1)

    def reconstruct(self) -> Tensor:
        """The cube map [6, S, S, C] these coefficients represent."""
        return cubemap_from_wavelets(self.dense())

    def energy(self) -> Tensor:
        """Sum of squared coefficients: by Parseval, the squared L2 norm of the reconstruction."""
        return (self.values**2).sum()

    def face_row_col(self) -> Tensor:
        """Indices as (face, row, col) [K, 3], the 2D wavelet positions a network can embed."""
        face, rest = self.indices // (self.size * self.size), self.indices % (self.size * self.size)
        return torch.stack((face, rest // self.size, rest % self.size), dim=-1)


def select_top_k(
    coefficients: Tensor, k: int, weighting: Literal["magnitude", "area"] = "magnitude"
) -> SparseWavelets:
    """The k coefficients of [6, S, S, C] with the largest norm over channels, optionally times their
    support fraction ("area": prefers coarse wavelets, as in NRH03's area-weighted selection)."""
    size = coefficients.shape[1]
    score = coefficients.norm(dim=-1)
    if weighting == "area":
        score = score * support_fraction(size, score.dtype).to(score.device)
    elif weighting != "magnitude":
        raise ValueError(f"weighting must be 'magnitude' or 'area', got {weighting!r}")
    flat = coefficients.reshape(-1, coefficients.shape[-1])
    indices = torch.topk(score.reshape(-1), min(k, score.numel())).indices
    return SparseWavelets(indices, flat[indices], size)
