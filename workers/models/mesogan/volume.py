"""The numerics every mesogan ray shares: the integrated encoding of height, the mipmapped feature plane,
volume quadrature and the tonemap (Diolatzis 2022, Sec. 6.2.3, 6.2.6-6.2.7).

All are pointwise in the queried sample (no image-space neighbourhood), which is what makes the rendered
material view-consistent and usable inside a path tracer (Sec. 6.2.2).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

MAX_OPTICAL_DEPTH = 1e4  # per sample: exp(-1e4) is 0 in float64, and sums of these stay finite
TONEMAP_MAX = 1.0 - 1e-4  # y = x / (x + 1) is clamped below 1 so the inverse stays finite


def integrated_encoding(mean: Tensor, variance: Tensor, frequencies: int) -> Tensor:
    """Eq. 6.2 per frequency: [sin(2^k mu), cos(2^k mu)] * exp(-1/2 4^k var), k < `frequencies`: the
    expectation of the plain encoding over x ~ N(mu, var), so wide footprints lose their high frequencies.
    `mean` and `variance` are (...,) heights already scaled to radians; returns (..., 2 * frequencies)."""
    scales = 2.0 ** torch.arange(frequencies, device=mean.device, dtype=mean.dtype)
    angle = mean[..., None] * scales
    damping = torch.exp(-0.5 * variance[..., None] * scales**2)
    return torch.cat([torch.sin(angle) * damping, torch.cos(angle) * damping], dim=-1)


def mip_stack(plane: Tensor, levels: int) -> list[Tensor]:
    """Level 0 is `plane` (B, C, R, R); each next level is a 2x2 box filter of the previous one."""
    stack = [plane]
    for _ in range(levels - 1):
        stack.append(F.avg_pool2d(stack[-1], 2))
    return stack


def mip_level(radius: Tensor, texel: float, levels: int) -> Tensor:
    """The continuous level whose texel matches a footprint of `radius` (plane units): log2(r / texel),
    clamped to [0, levels - 1]."""
    return torch.log2(torch.clamp(radius / texel, min=1e-12)).clamp(0.0, levels - 1)


def sample_mipmapped(stack: list[Tensor], uv: Tensor, level: Tensor) -> Tensor:
    """Trilinear lookup: bilinear in the two levels around `level` (B, N), blended linearly; `uv` (B, N, 2)
    in [0, 1] over the plane (clamped at its border). Returns (B, N, C). Continuous in `level`: at an
    integer level the other level's weight is exactly zero. Levels above the highest one asked for are not
    read (close views on a deep stack read one or two)."""
    grid = (uv * 2.0 - 1.0)[:, :, None, :]
    used = min(len(stack), int(level.detach().max().ceil()) + 1) if level.numel() else 1
    samples = torch.stack(
        [
            F.grid_sample(m, grid, mode="bilinear", padding_mode="border", align_corners=False)[..., 0]
            for m in stack[:used]
        ],
        dim=-1,
    )  # (B, C, N, L)
    lower = level.floor().long().clamp(0, used - 1)
    upper = (lower + 1).clamp(max=used - 1)
    weight = (level - lower.to(level.dtype))[:, None, :]
    index = lambda i: i[:, None, :, None].expand(-1, samples.shape[1], -1, 1)  # noqa: E731
    low = samples.gather(-1, index(lower))[..., 0]
    high = samples.gather(-1, index(upper))[..., 0]
    return (low * (1 - weight) + high * weight).permute(0, 2, 1)


def footprint_radius(axis_variance: Tensor, radial_variance: Tensor, direction_z: Tensor) -> Tensor:
    """r = min(a, b) of the ellipse a cone segment's Gaussian projects to on the tangent plane (Sec. 6.2.7).

    The Gaussian has variance `axis_variance` along the ray and `radial_variance` across it; dropping the
    height axis leaves variance r^2 across the ray's plane direction and r^2 z^2 + s^2 (1 - z^2) along it
    (z the ray's height component), so at grazing angles the minor axis is the cone's own radius."""
    z2 = direction_z**2
    along = radial_variance * z2 + axis_variance * (1 - z2)
    return torch.sqrt(torch.minimum(radial_variance, along))


def composite(density: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
    """Quadrature weights w_i = T_i (1 - exp(-sigma_i delta_i)) and the transmittance left after the last
    sample (..., ) along the last axis; sum(w) + T_final = 1 exactly, and huge densities give no NaN."""
    optical = (density * deltas).clamp(0.0, MAX_OPTICAL_DEPTH)
    alpha = -torch.expm1(-optical)
    # Exclusive sum (no cumsum - optical: a huge sample would swallow its predecessors in float32).
    before = torch.cat([torch.zeros_like(optical[..., :1]), torch.cumsum(optical[..., :-1], dim=-1)], -1)
    transmittance = torch.exp(-before)
    weights = transmittance * alpha
    final = torch.exp(-optical.sum(-1))
    return weights, final


def tonemap(x: Tensor) -> Tensor:
    """Reinhard x / (x + 1) (Sec. 6.2.3): negatives clamp to 0, +inf maps to `TONEMAP_MAX`."""
    x = torch.nan_to_num(x.clamp(min=0.0), posinf=torch.finfo(x.dtype).max)
    return torch.clamp(x / (x + 1.0), max=TONEMAP_MAX)


def inverse_tonemap(y: Tensor) -> Tensor:
    """y / (1 - y), with y clamped to [0, TONEMAP_MAX] so every output is finite."""
    y = y.clamp(0.0, TONEMAP_MAX)
    return y / (1.0 - y)


HEIGHT_TO_RADIANS = math.pi  # slab height 1 spans half a period of the lowest frequency
