"""Cube maps (directions, solid angles, lat-long round trip) and Haar wavelets on them."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from workers.nn.cubemap import (
    cubemap_directions,
    cubemap_solid_angles,
    cubemap_to_latlong,
    direction_to_face_uv,
    direction_to_latlong,
    latlong_solid_angles,
    latlong_to_cubemap,
    latlong_to_direction,
)
from workers.nn.haar import (
    cubemap_from_wavelets,
    cubemap_wavelets,
    haar2d,
    inverse_haar2d,
    select_top_k,
    support_fraction,
)


def test_haar_reconstructs_exactly_and_is_orthonormal():
    x = torch.randn(3, 6, 16, 16, dtype=torch.float64)
    c = haar2d(x)
    assert torch.allclose(inverse_haar2d(c), x, atol=1e-12)
    assert (c**2).sum().item() == pytest.approx((x**2).sum().item(), rel=1e-12)  # Parseval
    # The transform of each basis image gives an orthonormal matrix.
    basis = torch.eye(64, dtype=torch.float64).view(64, 8, 8)
    matrix = haar2d(basis).view(64, 64)
    assert torch.allclose(matrix @ matrix.T, torch.eye(64, dtype=torch.float64), atol=1e-12)


def test_haar_of_constant_is_one_scaling_coefficient():
    c = haar2d(torch.full((8, 8), 2.0))
    assert c[0, 0].item() == pytest.approx(16.0) and c.abs().sum().item() == pytest.approx(16.0)
    with pytest.raises(ValueError):
        haar2d(torch.zeros(6, 6))


def test_support_fraction_matches_basis_functions():
    size = 8
    basis = torch.zeros(size * size, size, size, dtype=torch.float64)
    basis.view(size * size, -1)[torch.arange(size * size), torch.arange(size * size)] = 1
    functions = inverse_haar2d(basis)
    covered = (functions != 0).sum(dim=(1, 2)).view(size, size).double() / size**2
    assert torch.allclose(covered, support_fraction(size, torch.float64))


def test_cubemap_wavelet_round_trip_and_top_k_energy():
    torch.manual_seed(0)
    cube = torch.rand(6, 16, 16, 3, dtype=torch.float64) ** 4
    coefficients = cubemap_wavelets(cube)
    assert torch.allclose(cubemap_from_wavelets(coefficients), cube, atol=1e-12)
    k = 50
    selected = select_top_k(coefficients, k)
    direct = np.sort((coefficients.norm(dim=-1) ** 2).flatten().numpy())[::-1][:k].sum()
    assert selected.energy().item() == pytest.approx(direct, rel=1e-12)
    # Parseval again: the reconstruction has exactly the selected energy, and the rest is the error.
    approximation = selected.reconstruct()
    assert (approximation**2).sum().item() == pytest.approx(direct, rel=1e-10)
    error = ((cube - approximation) ** 2).sum().item()
    assert error == pytest.approx((cube**2).sum().item() - direct, rel=1e-8)
    faces_rows_cols = selected.face_row_col()
    assert torch.equal(coefficients[tuple(faces_rows_cols.T)], selected.values)


def test_area_weighted_selection_prefers_coarse_wavelets():
    coefficients = torch.zeros(6, 8, 8, 1)
    coefficients[0, 7, 7] = 1.0  # finest detail, support 1/16 of the face
    coefficients[1, 0, 1] = 0.5  # coarsest detail, the whole face
    assert select_top_k(coefficients, 1).face_row_col().tolist() == [[0, 7, 7]]
    assert select_top_k(coefficients, 1, weighting="area").face_row_col().tolist() == [[1, 0, 1]]
    with pytest.raises(ValueError):
        select_top_k(coefficients, 1, weighting="volume")


def test_solid_angles_sum_to_four_pi():
    assert cubemap_solid_angles(32, torch.float64).sum().item() == pytest.approx(4 * math.pi, rel=1e-12)
    assert latlong_solid_angles(64, 128, torch.float64).sum().item() == pytest.approx(4 * math.pi, rel=1e-12)
    # A cube texel's solid angle is close to its area times cos^3 / r^2 at the centre.
    dirs = cubemap_directions(32, torch.float64)
    approx = (2 / 32) ** 2 * dirs.abs().max(dim=-1).values ** 3
    assert torch.allclose(cubemap_solid_angles(32, torch.float64), approx, rtol=2e-3)


def test_direction_conventions():
    dirs = cubemap_directions(8, torch.float64)
    face, s, t = direction_to_face_uv(dirs)
    assert torch.equal(face, torch.arange(6)[:, None, None].expand(6, 8, 8))
    centres = (torch.arange(8, dtype=torch.float64) + 0.5) / 8
    assert torch.allclose(s, centres.expand(6, 8, 8)) and torch.allclose(t, centres[:, None].expand(6, 8, 8))
    u, v = direction_to_latlong(torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]))
    assert v[0].item() == pytest.approx(0.0) and (u[1].item(), v[1].item()) == pytest.approx((0.0, 0.5))
    assert u[2].item() == pytest.approx(0.25)
    w = torch.rand(100, 3, dtype=torch.float64) * 2 - 1
    assert torch.allclose(latlong_to_direction(*direction_to_latlong(w)), w / w.norm(dim=-1, keepdim=True))


def test_latlong_cubemap_round_trip_of_smooth_function():
    def smooth(d: torch.Tensor) -> torch.Tensor:
        return torch.stack((1 + d[..., 0], 1 + d[..., 1] * d[..., 2], torch.exp(d[..., 1])), dim=-1)

    height, width = 64, 128
    v, u = torch.meshgrid(
        (torch.arange(height, dtype=torch.float64) + 0.5) / height,
        (torch.arange(width, dtype=torch.float64) + 0.5) / width,
        indexing="ij",
    )
    latlong = smooth(latlong_to_direction(u, v))
    cube = latlong_to_cubemap(latlong, 32)
    assert (cube - smooth(cubemap_directions(32, torch.float64))).abs().max() < 0.02
    back = cubemap_to_latlong(cube, height, width)
    assert (back - latlong).abs().max() < 0.03
    assert (back - latlong).abs().mean() < 0.005


def test_latlong_to_cubemap_preserves_integral_of_a_small_bright_source():
    latlong = torch.zeros(128, 256, 1, dtype=torch.float64)
    latlong[60:62, 100:102] = 1000.0
    weights = latlong_solid_angles(128, 256, torch.float64)[..., None]
    power = (latlong * weights).sum().item()
    cube = latlong_to_cubemap(latlong, 16, supersample=8)
    cube_power = (cube * cubemap_solid_angles(16, torch.float64)[..., None]).sum().item()
    assert cube_power == pytest.approx(power, rel=0.1)
