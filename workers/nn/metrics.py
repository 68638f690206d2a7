"""Image error metrics for reports. Inputs: float32 linear RGB images (H, W, 3), numpy or torch.

LDR metrics (PSNR, SSIM, LDR FLIP) see images through a defined tonemap: by default "srgb", i.e. clamp to
[0, 1] and apply the sRGB curve, which is what a PNG preview shows. HDR FLIP and the relative errors work
on the linear values.

An image with a NaN or infinite pixel has no error to measure: every metric of it is NaN, so a broken
render can never look finite (or, after clamping, black and nearly right) in a report.
"""

from __future__ import annotations

import math

import flip_evaluator
import numpy as np
import torch
from torch import Tensor

from workers.nn.ssim import ssim_index
from workers.nn.tonemap import TONEMAPS

ImageLike = np.ndarray | Tensor
MAX_PSNR_DB = 100.0
"""PSNR of identical images: the MSE is floored at peak^2 * 1e-10 so reports stay finite (and JSON-safe)."""
HDR_MIN_PEAK = 1e-6  # below, flip-evaluator's start exposure exceeds its stop exposure and it exits


def _as_tensor(image: ImageLike) -> Tensor:
    tensor = torch.as_tensor(np.asarray(image.detach().cpu() if isinstance(image, Tensor) else image))
    if tensor.dim() != 3:
        raise ValueError(f"expected an image (H, W, C), got shape {tuple(tensor.shape)}")
    tensor = tensor.to(torch.float64)
    return tensor.where(torch.isfinite(tensor), math.nan)  # inf too: tonemaps and clamps would hide it


def _pair(reference: ImageLike, test: ImageLike) -> tuple[Tensor, Tensor]:
    ref, tst = _as_tensor(reference), _as_tensor(test)
    if ref.shape != tst.shape:
        raise ValueError(f"image shapes differ: {tuple(ref.shape)} vs {tuple(tst.shape)}")
    return ref, tst


def _finite(*images: Tensor) -> bool:
    """No NaN pixel: metrics that clamp, or hand the images to flip-evaluator, check this first."""
    return all(bool(torch.isfinite(image).all()) for image in images)


def _tonemapped(reference: ImageLike, test: ImageLike, tonemap: str) -> tuple[Tensor, Tensor]:
    if tonemap not in TONEMAPS:
        raise ValueError(f"unknown tonemap {tonemap!r}; choose from {sorted(TONEMAPS)}")
    ref, tst = _pair(reference, test)
    return TONEMAPS[tonemap](ref), TONEMAPS[tonemap](tst)


def psnr(reference: ImageLike, test: ImageLike, peak: float = 1.0, tonemap: str = "srgb") -> float:
    """Peak signal-to-noise ratio in dB after `tonemap`, capped at MAX_PSNR_DB."""
    ref, tst = _tonemapped(reference, test, tonemap)
    if not _finite(ref, tst):
        return math.nan
    mse = max(float(((ref - tst) ** 2).mean()), peak**2 * 10 ** (-MAX_PSNR_DB / 10))
    return 10 * math.log10(peak**2 / mse)


def ssim(a: ImageLike, b: ImageLike, tonemap: str = "srgb") -> float:
    """Mean SSIM after `tonemap` (1 for identical images)."""
    ref, tst = _tonemapped(a, b, tonemap)
    return float(ssim_index(ref, tst)) if _finite(ref, tst) else math.nan


def dssim(a: ImageLike, b: ImageLike, tonemap: str = "srgb") -> float:
    """(1 - SSIM) / 2: 0 for identical images."""
    return (1 - ssim(a, b, tonemap)) / 2


def flip(reference: ImageLike, test: ImageLike, hdr: bool = True, mask: np.ndarray | None = None) -> float:
    """Mean FLIP error (Andersson et al. 2020; the `flip-evaluator` package), 0 for identical images;
    with `mask` (H, W) the mean over the masked pixels only (e.g. excluding empty background).

    HDR mode takes the linear images (negatives clamped to 0) and lets FLIP choose its exposure range; LDR
    mode takes them clamped to [0, 1] as linear values (FLIP applies no sRGB decoding). A reference whose
    peak is below HDR_MIN_PEAK has no exposure range to choose from and is compared in LDR mode.
    """
    ref, tst = _pair(reference, test)
    if not _finite(ref, tst):
        return math.nan
    if hdr and float(ref.max()) < HDR_MIN_PEAK:
        hdr = False  # flip-evaluator ends the whole process when an HDR reference is (nearly) black
    ref, tst = (x.clamp(min=0.0) if hdr else x.clamp(0.0, 1.0) for x in (ref, tst))
    error_map, mean_error, _ = flip_evaluator.evaluate(
        ref.float().numpy(), tst.float().numpy(), "HDR" if hdr else "LDR", inputsRGB=False, applyMagma=False
    )
    if mask is None:
        return float(mean_error)
    mask = np.asarray(mask, bool)
    if mask.shape != ref.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match the images' {tuple(ref.shape[:2])}")
    return float(np.asarray(error_map).reshape(mask.shape)[mask].mean()) if mask.any() else math.nan


def mape(reference: ImageLike, test: ImageLike, eps: float = 1e-2) -> float:
    """Mean absolute percentage error |t - r| / (|r| + eps), as a fraction."""
    ref, tst = _pair(reference, test)
    return float(((tst - ref).abs() / (ref.abs() + eps)).mean())


def relative_mse(reference: ImageLike, test: ImageLike, eps: float = 1e-2) -> float:
    """Mean of (t - r)^2 / (r^2 + eps): the path-tracing community's relMSE."""
    ref, tst = _pair(reference, test)
    return float(((tst - ref) ** 2 / (ref**2 + eps)).mean())
