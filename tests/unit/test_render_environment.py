"""The lat-long environment's sampling tables: guided searches find what a binary search finds, and a
sample's pdf and radiance are what a lookup of its direction answers (MIS and the light estimate rely on
both being the same function)."""

from __future__ import annotations

import numpy as np
from numba import njit

from workers.render.environment import EnvironmentMapLight, _bilinear_maxima, _cdf, _guide, sample
from workers.render.kernels import guided_search
from workers.render.sampling import luminance
from workers.scene.format.spec import euler_xyz


@njit(cache=False)
def _guided_searches(cdf, guide, u):
    return np.array([guided_search(cdf, guide, x) for x in u])


def test_guided_search_finds_what_searchsorted_finds():
    rng = np.random.default_rng(0)
    for n in (1, 2, 7, 64, 1000):
        prob = rng.random(n) * (rng.random(n) < 0.6)  # many empty entries: runs of equal cdf values
        prob[rng.integers(n)] += 0.1
        cdf = _cdf(prob)
        u = np.concatenate([rng.random(4000), cdf[:-1], np.nextafter(cdf[:-1], 0), [0.0]])
        expected = np.searchsorted(cdf, u, side="right")
        np.testing.assert_array_equal(_guided_searches(cdf, _guide(cdf), u), expected)


def test_samples_carry_the_pdf_and_radiance_of_their_directions():
    rng = np.random.default_rng(1)
    image = (rng.random((16, 32, 3)) ** 6).astype(np.float32)  # peaked, like a sky with a sun
    image[:, 5:8] = 0.0  # dark columns: the middle one, which the lookup never lights, is never drawn
    light = EnvironmentMapLight(image, euler_xyz((20.0, 75.0, -10.0)))
    directions, pdf, radiance = sample(rng.random((20000, 2)), light.tables)
    looked_up, looked_up_pdf = light.radiance_and_pdf(directions)
    np.testing.assert_allclose(pdf, looked_up_pdf, rtol=1e-9)
    np.testing.assert_allclose(radiance, looked_up, rtol=1e-9, atol=1e-12)
    assert (pdf > 0).all()


def test_sample_frequencies_follow_the_texel_probabilities():
    rng = np.random.default_rng(2)
    image = (rng.random((8, 16, 3)) ** 4).astype(np.float32)
    light = EnvironmentMapLight(image, np.eye(3))
    n = 200_000
    directions, _, _ = sample(rng.random((n, 2)), light.tables)
    u = np.arctan2(directions[:, 0], -directions[:, 2]) / (2 * np.pi) % 1.0
    v = np.arccos(np.clip(directions[:, 1], -1, 1)) / np.pi
    texel = np.minimum((v * 8).astype(int), 7) * 16 + np.minimum((u * 16).astype(int), 15)
    counts = np.bincount(texel, minlength=128)
    theta = (np.arange(8) + 0.5) / 8 * np.pi
    weights = _bilinear_maxima(luminance(image.astype(np.float64))) * np.sin(theta)[:, None]
    expected = n * (weights / weights.sum()).ravel()
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 127 + 5 * np.sqrt(2 * 127)  # 127 degrees of freedom, 5 sigma


def test_texels_are_drawn_by_the_largest_value_their_lookup_takes():
    """`_bilinear_maxima` bounds the bilinear lookup over each texel and is reached in it: the sampling
    weight of a texel next to a bright one is what the lookup blends into it, not its own dim value."""
    rng = np.random.default_rng(3)
    h, w = 8, 16
    image = (rng.random((h, w, 3)) ** 6).astype(np.float32)
    image[3, 0] = 50.0  # a sun on the seam
    light = EnvironmentMapLight(image, np.eye(3))
    k = 40  # intervals per texel side: points on its corners, edge midpoints and centre among them
    v = np.clip(np.arange(h * k + 1) / (h * k), 1e-9, 1 - 1e-9)
    u = np.arange(w * k + 1) / (w * k)
    t, p = np.meshgrid(v * np.pi, u * 2 * np.pi, indexing="ij")
    dirs = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], -1).reshape(-1, 3)
    looked_up = luminance(light.radiance(dirs)).reshape(t.shape)
    over_texels = np.array(
        [
            [looked_up[r * k : (r + 1) * k + 1, c * k : (c + 1) * k + 1].max() for c in range(w)]
            for r in range(h)
        ]
    )
    np.testing.assert_allclose(over_texels, _bilinear_maxima(luminance(image.astype(np.float64))), rtol=1e-5)
