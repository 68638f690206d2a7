"""Tonemaps used by losses and metrics: mu-law for signed HDR values, sRGB and Reinhard for display."""

from __future__ import annotations

import math

import torch
from torch import Tensor


class _MuLaw(torch.autograd.Function):
    """sign(x) log(1 + mu |x|) / log(1 + mu) with its true slope at 0 (autograd of sign() gives 0 there,
    which would stall a network whose ReLU output sits exactly at zero)."""

    @staticmethod
    def forward(ctx, x: Tensor, mu: float) -> Tensor:
        ctx.save_for_backward(x)
        ctx.mu = mu
        return torch.sign(x) * torch.log1p(mu * x.abs()) / math.log1p(mu)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None]:
        (x,) = ctx.saved_tensors
        return grad * ctx.mu / ((1 + ctx.mu * x.abs()) * math.log1p(ctx.mu)), None


def mu_law(x: Tensor, mu: float = 10.0) -> Tensor:
    """Odd log tonemap (Kalantari and Ramamoorthi 2017; Raghavan et al. 2023 use mu = 10), defined for
    negative values, which wavelet-domain predictions produce; maps [-1, 1] onto [-1, 1]."""
    if mu <= 0:
        raise ValueError(f"mu must be positive, got {mu}")
    return _MuLaw.apply(x, mu)


def srgb_encode(linear: Tensor) -> Tensor:
    """Clamp to [0, 1] and apply the sRGB transfer curve: what an 8-bit preview shows."""
    c = linear.clamp(0.0, 1.0)
    return torch.where(c <= 0.0031308, 12.92 * c, 1.055 * c.clamp(min=0.0031308) ** (1 / 2.4) - 0.055)


def reinhard(linear: Tensor) -> Tensor:
    """x / (1 + x) per channel (negatives clamped to 0), then sRGB: keeps highlights above 1 distinct."""
    c = linear.clamp(min=0.0)
    return srgb_encode(c / (1 + c))


TONEMAPS = {"srgb": srgb_encode, "reinhard": reinhard, "none": lambda x: x}
