"""Shared-input composite, spherical harmonics, Fourier features, integrated encoding, one-blob."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from workers.nn.encodings import (
    FourierFeatures,
    HashGrid,
    IntegratedPositionalEncoding,
    OneBlob,
    SharedInputsEncoding,
    SphericalHarmonics,
    octave_frequencies,
    spherical_harmonics,
)


def test_shared_inputs_encoding_concatenates_and_shares_gradients():
    grid = HashGrid(3, n_levels=2, log2_hashmap_size=10, base_resolution=4).double()
    grid.table.data.uniform_(-1, 1)
    composite = SharedInputsEncoding(grid, n_inputs=2)
    p0, p1 = torch.rand(5, 3, dtype=torch.float64), torch.rand(5, 3, dtype=torch.float64)
    out = composite(torch.cat((p0, p1), dim=-1))
    assert out.shape == (5, 2 * grid.n_output_dims) == (5, composite.n_output_dims)
    assert torch.allclose(out, torch.cat((grid(p0), grid(p1)), dim=-1))
    out.sum().backward()
    combined = grid.table.grad.clone()
    packed = torch.tensor([[0.31, 0.47, 0.83, 0.62, 0.12, 0.27]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(composite, (packed,))
    grid.table.grad = None
    (grid(p0).sum() + grid(p1).sum()).backward()
    assert torch.allclose(combined, grid.table.grad)


def _sphere_quadrature(n_theta: int = 24, n_phi: int = 48) -> tuple[torch.Tensor, torch.Tensor]:
    """Gauss-Legendre in cos(theta) x uniform phi: exact for spherical polynomials of degree < 2 n_theta."""
    z, w = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    dirs = np.stack((r * np.cos(pp), r * np.sin(pp), zz), axis=-1).reshape(-1, 3)
    weights = (w[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return torch.from_numpy(dirs), torch.from_numpy(weights)


def test_spherical_harmonics_are_orthonormal_to_degree_8():
    dirs, weights = _sphere_quadrature()
    y = spherical_harmonics(dirs, degree=8)
    assert y.shape == (dirs.shape[0], 81)
    gram = y.T @ (weights[:, None] * y)
    assert torch.allclose(gram, torch.eye(81, dtype=torch.float64), atol=1e-6)


def test_spherical_harmonics_known_values_and_poles():
    d = torch.tensor([[0.3, 0.5, 0.81]], dtype=torch.float64)
    x, y, z = (d / d.norm()).unbind(-1)
    values = spherical_harmonics(d, degree=2)[0]
    expected = [
        0.28209479177387814,
        -0.4886025119029199 * y,
        0.4886025119029199 * z,
        -0.4886025119029199 * x,
        1.0925484305920792 * x * y,
        -1.0925484305920792 * y * z,
        0.31539156525252005 * (3 * z * z - 1),
        -1.0925484305920792 * x * z,
        0.5462742152960396 * (x * x - y * y),
    ]
    assert torch.allclose(values, torch.tensor([float(e) for e in expected], dtype=torch.float64))
    poles = spherical_harmonics(torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]), 8)
    assert torch.isfinite(poles).all()
    # At the poles only m = 0 survives: Y_l^0 = sqrt((2l+1)/4pi) (+-1)^l.
    m0 = [l * l + l for l in range(9)]
    assert torch.allclose(
        poles[0, m0], torch.tensor([math.sqrt((2 * l + 1) / (4 * math.pi)) for l in range(9)])
    )
    assert torch.allclose(poles[1, m0], poles[0, m0] * torch.tensor([(-1.0) ** l for l in range(9)]))
    assert poles[0].abs().sum().item() == pytest.approx(poles[0, m0].abs().sum().item(), abs=1e-6)


def test_spherical_harmonics_gradcheck_and_module():
    d = torch.randn(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: spherical_harmonics(v, 8), (d,))
    assert SphericalHarmonics(degree=3)(d).shape == (4, 16)
    with pytest.raises(ValueError):
        spherical_harmonics(d, degree=9)


def test_fourier_features_layout_and_values():
    encoding = FourierFeatures(2, octave_frequencies(3))
    x = torch.tensor([[0.25, -0.5]], dtype=torch.float64)
    out = encoding(x)
    assert out.shape == (1, encoding.n_output_dims) == (1, 2 * 7)
    assert torch.allclose(out[0, :2], x[0])
    assert out[0, 2 + 2].item() == pytest.approx(math.sin(4 * math.pi * 0.25))  # dim 0, frequency 4 pi
    assert out[0, 2 + 6 + 3].item() == pytest.approx(math.cos(math.pi * -0.5))  # cos, dim 1, frequency pi
    assert FourierFeatures(3, [1.0, 2.0], include_input=False)(torch.rand(5, 3)).shape == (5, 12)
    assert torch.autograd.gradcheck(encoding, (torch.rand(3, 2, dtype=torch.float64, requires_grad=True),))


def test_integrated_encoding_limits_and_gradcheck():
    ipe = IntegratedPositionalEncoding(2, octave_frequencies(4))
    mean = torch.rand(6, 2, dtype=torch.float64, requires_grad=True)
    zero_var = torch.zeros(6, 2, dtype=torch.float64)
    plain = FourierFeatures(2, octave_frequencies(4), include_input=False).double()
    assert torch.allclose(ipe(mean, zero_var), plain(mean))  # zero variance: plain Fourier features
    huge = ipe(mean, torch.full((6, 2), 1e6, dtype=torch.float64))
    assert torch.all(huge.abs() < 1e-12)  # infinitely blurred: everything averages out
    variance = torch.rand(6, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(ipe, (mean, variance))


def test_integrated_encoding_equals_monte_carlo_expectation():
    ipe = IntegratedPositionalEncoding(1, [1.0, 3.0])
    mean, var = torch.tensor([[0.3]], dtype=torch.float64), torch.tensor([[0.05]], dtype=torch.float64)
    samples = mean + var.sqrt() * torch.randn(
        200_000, 1, dtype=torch.float64, generator=torch.Generator().manual_seed(0)
    )
    expected = FourierFeatures(1, [1.0, 3.0], include_input=False).double()(samples).mean(0)
    assert torch.allclose(ipe(mean, var)[0], expected, atol=5e-3)


def test_one_blob_is_a_soft_one_hot():
    encoding = OneBlob(2, n_bins=16)
    x = torch.tensor([[0.5, 0.03]], dtype=torch.float64, requires_grad=True)
    out = encoding(x).view(2, 16)
    assert out.argmax(-1).tolist() == [7, 0] or out.argmax(-1).tolist() == [8, 0]
    assert torch.all(out >= 0) and torch.all(out.sum(-1) <= 1 + 1e-12)
    assert out[0].sum().item() == pytest.approx(1.0, abs=1e-3)  # centred blob: almost all mass inside [0, 1]
    assert torch.autograd.gradcheck(encoding, (x,))
