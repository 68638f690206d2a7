"""The G-buffer-guided à-trous filter (`workers.render.denoise`)."""

from __future__ import annotations

import numpy as np
import pytest

from workers.render.denoise import AtrousSettings, Guides, atrous

SIZE = 24


def plane_guides(normal=(0.0, 0.0, 1.0), albedo=0.5, mask=None) -> Guides:
    """A camera looking down -z at the plane z = 0: one pixel is 0.1 wide."""
    py, px = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    position = np.stack([0.1 * px, 0.1 * py, np.zeros_like(px)], axis=-1)
    return Guides(
        mask=np.ones((SIZE, SIZE), bool) if mask is None else mask,
        normal=np.broadcast_to(np.asarray(normal, np.float64), (SIZE, SIZE, 3)).copy(),
        position=position,
        footprint=np.full((SIZE, SIZE), 0.1),
        object_id=np.zeros((SIZE, SIZE), np.int64),
        albedo=np.full((SIZE, SIZE, 3), albedo),
    )


@pytest.mark.parametrize("with_variance", [False, True])
def test_a_constant_image_stays_constant_on_any_geometry(with_variance):
    """Bumpy geometry of two objects: the taps' weights vary, yet they are normalised."""
    rng = np.random.default_rng(0)
    guides = plane_guides()
    guides.normal += 0.3 * rng.normal(size=(SIZE, SIZE, 3))
    guides.normal /= np.linalg.norm(guides.normal, axis=-1, keepdims=True)
    guides.position[..., 2] += 0.05 * rng.normal(size=(SIZE, SIZE))
    guides.object_id[:, SIZE // 2 :] = 1
    image = np.full((SIZE, SIZE, 3), 0.37, np.float32)
    variance = rng.uniform(0, 1, (SIZE, SIZE)) if with_variance else None
    out = atrous(image, guides, variance=variance)
    np.testing.assert_allclose(out, image, rtol=1e-6)


def test_noise_on_a_plane_is_reduced():
    rng = np.random.default_rng(1)
    noisy = (0.5 + 0.2 * rng.standard_normal((SIZE, SIZE, 3))).astype(np.float32)
    out = atrous(noisy, plane_guides())
    assert np.std(out - 0.5) < 0.25 * np.std(noisy - 0.5)


def test_no_light_crosses_a_normal_edge():
    """Left half faces +z, right half +x (a right-angle crease): each side keeps its own radiance."""
    guides = plane_guides()
    guides.normal[:, SIZE // 2 :] = (1.0, 0.0, 0.0)
    image = np.zeros((SIZE, SIZE, 3), np.float32)
    image[:, : SIZE // 2] = 1.0
    out = atrous(image, guides, AtrousSettings(iterations=4))
    np.testing.assert_allclose(out[:, : SIZE // 2], 1.0, atol=1e-3)
    np.testing.assert_allclose(out[:, SIZE // 2 :], 0.0, atol=1e-3)


def test_no_light_crosses_a_depth_edge():
    """Same normal, but the right half lies 10 pixel footprints behind the left one."""
    guides = plane_guides()
    guides.position[:, SIZE // 2 :, 2] -= 1.0
    image = np.zeros((SIZE, SIZE, 3), np.float32)
    image[:, : SIZE // 2] = 1.0
    out = atrous(image, guides)
    assert np.abs(out[:, SIZE // 2 :]).max() < 1e-2
    assert np.abs(out[:, : SIZE // 2] - 1.0).max() < 1e-2


def test_a_shadow_edge_survives_through_the_luminance_term():
    """One plane, a sharp shadow edge the G-buffer does not show, low noise: with the variance given, the
    edge stays sharp; without it, the filter blurs it."""
    rng = np.random.default_rng(2)
    image = np.full((SIZE, SIZE, 3), 0.05)
    image[:, : SIZE // 2] = 1.0
    noisy = (image + 0.01 * rng.standard_normal(image.shape)).astype(np.float32)
    variance = np.full((SIZE, SIZE), 0.01**2)
    edge = slice(SIZE // 2 - 2, SIZE // 2 + 2)
    kept = atrous(noisy, plane_guides(), variance=variance)
    blurred = atrous(noisy, plane_guides())
    assert np.abs(kept[:, edge] - image[:, edge]).max() < 0.05
    assert np.abs(blurred[:, edge] - image[:, edge]).max() > 0.2


def test_pixels_outside_the_mask_are_untouched_and_never_mixed_in():
    mask = np.ones((SIZE, SIZE), bool)
    mask[:, :4] = False
    image = np.full((SIZE, SIZE, 3), 0.2, np.float32)
    image[:, :4] = 50.0  # the environment seen directly
    out = atrous(image, plane_guides(mask=mask))
    np.testing.assert_array_equal(out[:, :4], image[:, :4])
    np.testing.assert_allclose(out[:, 4:], 0.2, rtol=1e-6)


def test_texture_is_kept_by_demodulation():
    """Irradiance constant, albedo a checkerboard: the filtered radiance is the input."""
    guides = plane_guides()
    checker = np.indices((SIZE, SIZE)).sum(0) % 2
    guides.albedo = np.where(checker[..., None], 0.8, 0.2) * np.ones(3)
    image = (guides.albedo * 0.7).astype(np.float32)
    np.testing.assert_allclose(atrous(image, guides), image, rtol=1e-6)


def test_pixels_straddling_a_silhouette_are_left_raw():
    """Antialiasing mixes two objects in the pixels along their boundary, which the pixel-centre G-buffer
    does not describe: those keep their own values; the others are filtered."""
    rng = np.random.default_rng(3)
    guides = plane_guides()
    guides.object_id[:, SIZE // 2 :] = 1
    noisy = (0.5 + 0.2 * rng.standard_normal((SIZE, SIZE, 3))).astype(np.float32)
    out = atrous(noisy, guides)
    boundary = slice(SIZE // 2 - 1, SIZE // 2 + 1)
    np.testing.assert_array_equal(out[:, boundary], noisy[:, boundary])
    assert (out[:, : SIZE // 2 - 1] != noisy[:, : SIZE // 2 - 1]).all()
