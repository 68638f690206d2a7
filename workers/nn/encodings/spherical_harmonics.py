"""Real orthonormal spherical harmonics up to degree 8 (81 coefficients), for direction inputs.

Evaluated as polynomials in (x, y, z): P_l^m(z) (1 - z^2)^(m/2) is split into a Legendre-type
recurrence in z times Re/Im (x + iy)^m, so nothing divides by sin(theta) and the poles are exact.
Coefficient l*l + l + m holds Y_l^m, m = -l..l; negative m use sin(|m| phi). The Condon-Shortley phase
is included, matching tiny-cuda-nn and Sloan's "Stupid SH tricks" (Y_1^1 = -0.4886 x).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn
from torch.nn import functional as F

MAX_DEGREE = 8


def _normalisation(l: int, m: int) -> float:
    factor = (2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m)
    return math.sqrt(factor) * (math.sqrt(2.0) if m else 1.0)


def spherical_harmonics(directions: Tensor, degree: int = MAX_DEGREE) -> Tensor:
    """Y_l^m for l = 0..degree of directions [..., 3] (normalised here), as [..., (degree + 1)^2]."""
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"degree must be in 0..{MAX_DEGREE}, got {degree}")
    x, y, z = F.normalize(directions, dim=-1, eps=1e-12).unbind(-1)
    # cos_m + i sin_m = (x + iy)^m = sin^m(theta) e^{i m phi}
    cos_m, sin_m = [torch.ones_like(x)], [torch.zeros_like(x)]
    for _ in range(degree):
        cos_m.append(cos_m[-1] * x - sin_m[-1] * y)
        sin_m.append(cos_m[-2] * y + sin_m[-1] * x)
    # legendre[(l, m)] = P_l^m(z) / sin^m(theta), by the standard three-term recurrence in l
    legendre: dict[tuple[int, int], Tensor] = {}
    for m in range(degree + 1):
        legendre[(m, m)] = torch.full_like(z, (-1) ** m * math.prod(range(1, 2 * m, 2)))
        if m + 1 <= degree:
            legendre[(m + 1, m)] = (2 * m + 1) * z * legendre[(m, m)]
        for l in range(m + 2, degree + 1):
            legendre[(l, m)] = (
                (2 * l - 1) * z * legendre[(l - 1, m)] - (l + m - 1) * legendre[(l - 2, m)]
            ) / (l - m)
    columns = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            azimuthal = sin_m[-m] if m < 0 else cos_m[m]
            columns.append(_normalisation(l, abs(m)) * legendre[(l, abs(m))] * azimuthal)
    return torch.stack(columns, dim=-1)


class SphericalHarmonics(nn.Module):
    """Encode directions [..., 3] as their (degree + 1)^2 real spherical harmonics."""

    def __init__(self, degree: int = 4) -> None:
        super().__init__()
        self.degree = degree

    n_input_dims = 3

    @property
    def n_output_dims(self) -> int:
        return (self.degree + 1) ** 2

    def forward(self, directions: Tensor) -> Tensor:
        return spherical_harmonics(directions, self.degree)
