"""mesogan's pointwise numerics: the integrated encoding, mip selection, footprints, quadrature and the
tonemap (the hard cases of the issue and of notes B10)."""

from __future__ import annotations

import itertools
import math

import torch

from workers.models.mesogan.volume import (
    composite,
    footprint_radius,
    integrated_encoding,
    inverse_tonemap,
    mip_level,
    mip_stack,
    sample_mipmapped,
    tonemap,
)

F64 = torch.float64


def test_the_integrated_encoding_is_the_plain_one_at_zero_variance_and_the_gaussian_expectation():
    mean = torch.linspace(-3, 3, 7, dtype=F64)
    plain = integrated_encoding(mean, torch.zeros_like(mean), 4)
    scales = 2.0 ** torch.arange(4, dtype=F64)
    assert torch.allclose(
        plain, torch.cat([torch.sin(mean[:, None] * scales), torch.cos(mean[:, None] * scales)], -1)
    )
    assert torch.allclose(integrated_encoding(mean, torch.full_like(mean, 1e-12), 4), plain, atol=1e-10)
    generator = torch.Generator().manual_seed(0)
    mu, sigma, n = torch.tensor([0.7], dtype=F64), 0.3, 200_000
    x = mu + sigma * torch.randn(n, generator=generator, dtype=F64)
    samples = torch.cat([torch.sin(x[:, None] * scales), torch.cos(x[:, None] * scales)], -1)
    expected = integrated_encoding(mu, torch.tensor([sigma**2], dtype=F64), 4)[0]
    error = (samples.mean(0) - expected).abs()
    assert (error < 3 * samples.std(0) / math.sqrt(n) + 1e-12).all()
    magnitudes = [
        integrated_encoding(mu, torch.tensor([v], dtype=F64), 4).abs() for v in (0.0, 0.01, 0.1, 1.0)
    ]
    assert all((a >= b).all() for a, b in itertools.pairwise(magnitudes))


def test_mip_lookup_keeps_a_constant_averages_a_checkerboard_and_is_continuous_and_clamped():
    constant = torch.full((1, 2, 16, 16), 0.37)
    uv = torch.rand(1, 50, 2)
    for level in (0.0, 0.5, 1.7, 3.0):
        got = sample_mipmapped(mip_stack(constant, 4), uv, torch.full((1, 50), level))
        assert torch.allclose(got, torch.full_like(got, 0.37))
    checker = ((torch.arange(16)[:, None] + torch.arange(16)[None]) % 2).float()[None, None]
    coarse = sample_mipmapped(mip_stack(checker, 5), uv, torch.full((1, 50), 4.0))
    assert torch.allclose(coarse, torch.full_like(coarse, 0.5))
    plane = torch.rand(1, 3, 16, 16)
    stack = mip_stack(plane, 4)
    below = sample_mipmapped(stack, uv, torch.full((1, 50), 2.0 - 1e-7))
    at = sample_mipmapped(stack, uv, torch.full((1, 50), 2.0))
    assert (below - at).abs().max() < 1e-6
    assert mip_level(torch.tensor([1e-9, 1e9]), 0.25, 4).tolist() == [0.0, 3.0]


def test_footprint_is_round_at_normal_incidence_and_the_minor_axis_at_grazing_angles():
    radial, axis = torch.tensor(0.04), torch.tensor(0.09)
    normal = footprint_radius(axis, radial, torch.tensor(-1.0))
    assert torch.isclose(normal, radial.sqrt())
    grazing = footprint_radius(axis, radial, torch.tensor(-0.05))
    assert torch.isclose(grazing, radial.sqrt())  # the cone's own radius, not the stretched major axis
    short = footprint_radius(torch.tensor(0.0001), radial, torch.tensor(-0.05))
    assert short < radial.sqrt()


def test_quadrature_is_exact_for_constant_density_sums_to_one_and_survives_huge_density():
    deltas = torch.full((10,), 0.1, dtype=F64)
    weights, remaining = composite(torch.full((10,), 2.0, dtype=F64), deltas)
    assert torch.isclose(remaining, torch.tensor(math.exp(-2.0), dtype=F64))
    assert torch.isclose(weights.sum() + remaining, torch.tensor(1.0, dtype=F64))
    _, clear = composite(torch.zeros(10, dtype=F64), deltas)
    assert clear == 1.0
    split, split_remaining = composite(torch.full((20,), 2.0, dtype=F64), torch.full((20,), 0.05, dtype=F64))
    assert torch.isclose(split_remaining, remaining) and torch.isclose(split[:2].sum(), weights[0])
    huge, huge_remaining = composite(torch.tensor([0.0, 1e30, 1e38, 5.0]), torch.full((4,), 0.1))
    assert torch.isfinite(huge).all() and huge_remaining == 0 and torch.isclose(huge.sum(), torch.tensor(1.0))


def test_the_tonemap_round_trips_and_handles_negative_and_infinite_radiance():
    x = torch.tensor([0.0, 0.01, 1.0, 50.0, 1e3])
    assert torch.allclose(inverse_tonemap(tonemap(x)), x, rtol=1e-4)
    edge = tonemap(torch.tensor([-1.0, math.inf, math.nan]))
    assert edge[0] == 0 and torch.isfinite(edge[1]) and edge[1] < 1 and torch.isfinite(edge[2])
    assert torch.isfinite(inverse_tonemap(torch.tensor([1.0, 2.0, -0.5]))).all()
