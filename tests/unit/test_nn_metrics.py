"""Image metrics: identities, known values, orderings, input handling."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from workers.nn.metrics import MAX_PSNR_DB, dssim, flip, mape, psnr, relative_mse, ssim


@pytest.fixture
def image() -> np.ndarray:
    rng = np.random.default_rng(0)
    smooth = np.linspace(0, 1, 48, dtype=np.float32)
    return (smooth[:, None, None] * smooth[None, :, None] * rng.uniform(0.5, 1.0, 3)).astype(np.float32)


def test_identical_images(image):
    assert psnr(image, image) == MAX_PSNR_DB
    assert flip(image, image) == 0.0 and flip(image, image, hdr=False) == 0.0
    assert ssim(image, image) == pytest.approx(1.0) and dssim(image, image) == pytest.approx(0.0, abs=1e-7)
    assert mape(image, image) == 0.0 and relative_mse(image, image) == 0.0


def test_known_values(image):
    assert psnr(image * 0 + 0.5, image * 0 + 0.6, tonemap="none") == pytest.approx(20.0)
    assert psnr(np.full((4, 4, 3), 2.0), np.full((4, 4, 3), 2.2), peak=2.0, tonemap="none") == pytest.approx(
        20.0
    )
    ones = np.ones((4, 4, 3), np.float32)
    assert mape(ones, 1.5 * ones) == pytest.approx(0.5 / 1.01)
    assert relative_mse(ones, 1.5 * ones) == pytest.approx(0.25 / 1.01)
    assert dssim(image, image * 0.5) == pytest.approx((1 - ssim(image, image * 0.5)) / 2)


def test_metrics_order_errors_consistently(image):
    rng = np.random.default_rng(1)
    slightly = image + rng.normal(0, 0.01, image.shape).astype(np.float32)
    badly = image + rng.normal(0, 0.1, image.shape).astype(np.float32)
    assert psnr(image, slightly) > psnr(image, badly)
    assert ssim(image, slightly) > ssim(image, badly)
    assert 0 < flip(image, slightly) < flip(image, badly) <= 1
    assert 0 < flip(image, slightly, hdr=False) < flip(image, badly, hdr=False) <= 1
    assert relative_mse(image, slightly) < relative_mse(image, badly)
    assert mape(image, slightly) < mape(image, badly)


def test_hdr_images_and_tonemaps(image):
    bright = image * 50
    # Clamped sRGB saturates above 1; Reinhard and HDR FLIP still see the difference.
    assert psnr(np.full((4, 4, 3), 5.0), np.full((4, 4, 3), 9.0)) == MAX_PSNR_DB
    assert psnr(np.full((4, 4, 3), 5.0), np.full((4, 4, 3), 9.0), tonemap="reinhard") < 40
    assert flip(bright, bright * 1.5) > 0
    with pytest.raises(ValueError):
        psnr(image, image, tonemap="aces")


def test_accepts_tensors_and_rejects_mismatched_shapes(image):
    t = torch.from_numpy(image).requires_grad_()
    assert psnr(t, t * 0.9) == pytest.approx(psnr(image, image * 0.9))
    with pytest.raises(ValueError):
        psnr(image, image[:-1])
    with pytest.raises(ValueError):
        psnr(image[..., 0], image[..., 0])


def test_flip_of_a_black_reference_is_finite_and_sees_leaked_light():
    """flip-evaluator exits the process for a black HDR reference (a sealed box's interior); ours does not."""
    black = np.zeros((16, 16, 3), np.float32)
    leaked = black.copy()
    leaked[4:8, 4:8] = 0.5
    assert flip(black, black) == 0.0
    assert 0 < flip(black, leaked) <= 1
    assert flip(np.full_like(black, 1e-30), leaked) == flip(black, leaked)


def test_flip_mean_over_a_mask():
    rng = np.random.default_rng(0)
    image = rng.random((16, 24, 3)).astype(np.float32)
    worse = image.copy()
    worse[:8] += 0.5
    mask = np.zeros((16, 24), bool)
    mask[8:] = True
    assert flip(image, worse, mask=mask) < flip(image, worse) < flip(image, worse, mask=~mask)
    assert math.isnan(flip(image, worse, mask=np.zeros_like(mask)))  # no pixel measured is no score
    with pytest.raises(ValueError, match="mask shape"):
        flip(image, worse, mask=mask[:4])


METRICS = [psnr, ssim, dssim, flip, mape, relative_mse]


@pytest.mark.parametrize("metric", METRICS, ids=lambda m: m.__name__)
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("which", ["test", "reference"])
def test_a_non_finite_pixel_makes_every_metric_nan(image, metric, bad, which):
    """A broken render must not score finite: clamping and tonemaps would turn NaN or inf into plausible
    values (before, FLIP of an all-NaN frame was that of a black one)."""
    broken = image.copy()
    broken[3, 5, 1] = bad
    pair = (image, broken) if which == "test" else (broken, image)
    assert math.isnan(metric(*pair))
    assert math.isnan(metric(*(torch.from_numpy(x) for x in pair)))
