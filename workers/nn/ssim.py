"""Differentiable structural similarity (Wang et al. 2004) on channel-last images."""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn import functional as F

WINDOW = 11
SIGMA = 1.5
C1 = 0.01**2
C2 = 0.03**2


def _gaussian_window(size: int, like: Tensor) -> Tensor:
    coords = torch.arange(size, dtype=like.dtype, device=like.device) - (size - 1) / 2
    g = torch.exp(-(coords**2) / (2 * SIGMA**2))
    return g / g.sum()


def ssim_map(a: Tensor, b: Tensor) -> Tensor:
    """Per-pixel SSIM of images [..., H, W, C] with values in [0, 1] over the valid region.

    Gaussian window 11, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2 (data range 1); the window shrinks to the
    largest odd size that fits images smaller than 11 pixels.
    """
    if a.shape != b.shape or a.dim() < 3:
        raise ValueError(f"ssim needs two images [..., H, W, C] of one shape, got {a.shape} and {b.shape}")
    height, width, channels = a.shape[-3:]
    size = min(WINDOW, height - (height + 1) % 2, width - (width + 1) % 2)
    g = _gaussian_window(size, a)
    kernel = (g[:, None] * g[None, :]).expand(channels, 1, size, size)

    def blur(x: Tensor) -> Tensor:
        return F.conv2d(x, kernel, groups=channels)

    def to_nchw(x: Tensor) -> Tensor:
        return x.reshape(-1, height, width, channels).permute(0, 3, 1, 2)

    x, y = to_nchw(a), to_nchw(b)
    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    numerator = (2 * mu_x * mu_y + C1) * (2 * cov + C2)
    denominator = (mu_x**2 + mu_y**2 + C1) * (var_x + var_y + C2)
    out = (numerator / denominator).permute(0, 2, 3, 1)
    return out.reshape(*a.shape[:-3], *out.shape[1:])


def ssim_index(a: Tensor, b: Tensor) -> Tensor:
    """Mean SSIM (1 for identical images)."""
    return ssim_map(a, b).mean()
