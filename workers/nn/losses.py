"""Training losses of the five model kinds; each is finite for zeros, negatives and huge values."""

from __future__ import annotations

from torch import Tensor
from torch.nn import functional as F

from workers.nn.ssim import ssim_index
from workers.nn.tonemap import mu_law


def relative_l2(prediction: Tensor, target: Tensor, eps: float = 1e-2) -> Tensor:
    """(p - t)^2 / (sg(p)^2 + eps) (Lehtinen et al. 2018): unbiased on noisy Monte Carlo targets because the
    normaliser uses the (gradient-stopped) prediction, not the noisy target."""
    if eps <= 0:
        raise ValueError(f"eps must be positive, got {eps}")
    return ((prediction - target) ** 2 / (prediction.detach() ** 2 + eps)).mean()


def binary_cross_entropy(logits: Tensor, target: Tensor) -> Tensor:
    """BCE on logits (log-sum-exp form, finite for logits of any size)."""
    return F.binary_cross_entropy_with_logits(logits, target)


def mu_law_l2(prediction: Tensor, target: Tensor, mu: float = 10.0) -> Tensor:
    """||TM(p) - TM(t)||^2 with the signed mu-law tonemap (Raghavan et al. 2023, Sec. 5)."""
    return ((mu_law(prediction, mu) - mu_law(target, mu)) ** 2).mean()


def dssim(prediction: Tensor, target: Tensor) -> Tensor:
    """Structural dissimilarity (1 - SSIM) / 2 of images [..., H, W, C] in [0, 1]."""
    return (1 - ssim_index(prediction, target)) / 2


def l1_dssim(prediction: Tensor, target: Tensor, dssim_weight: float = 0.2) -> Tensor:
    """(1 - w) L1 + w DSSIM on images [..., H, W, C] in [0, 1]."""
    return (1 - dssim_weight) * mae(prediction, target) + dssim_weight * dssim(prediction, target)


def cosine_similarity_loss(prediction: Tensor, target: Tensor, eps: float = 1e-8) -> Tensor:
    """1 - cos(p, t) along the last dimension (e.g. normals); zero vectors count as orthogonal."""
    return (1 - F.cosine_similarity(prediction, target, dim=-1, eps=eps)).mean()


def categorical_cross_entropy(logits: Tensor, target: Tensor) -> Tensor:
    """Cross-entropy of logits [..., K] against class indices [...] (e.g. material ids)."""
    return F.cross_entropy(logits.reshape(-1, logits.shape[-1]), target.reshape(-1))


def mae(prediction: Tensor, target: Tensor) -> Tensor:
    """Mean absolute error."""
    return (prediction - target).abs().mean()
