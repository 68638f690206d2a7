"""Directional albedo E_s(mu) of a GGX dielectric reflection lobe, F D G / (4 cos_v) with the exact
dielectric Fresnel F of an IOR and single scattering: what the `pbr` family's energy-conserving diffuse
(Kulla & Conty 2017, albedo scaling) leaves to the diffuse base, 1 - E_s.

E_s at a cosine is the visible-normal quadrature `plastic` tabulates its coat with: E over the visible
normals m of F(v.m) G1(l, m), l the mirrored v, which is what the lobe's f cos / pdf averages to. Tables
hold E_s at cosines spaced evenly in sqrt(mu) (dense at grazing, where a smooth lobe's shadowing varies
fastest), interpolated linearly in mu, and E_avg = 2 int E_s(mu) mu dmu of that interpolant, computed
exactly (2-point Gauss-Legendre per interval integrates the quadratic exactly), so a white diffuse base
under the lobe reflects E_s + (1 - E_s) = 1 up to the table's error at cos_v alone. A constant roughness
gets a table at its alpha; textured roughness a 2-D table over perceptual roughness (alpha =
max(0.001, r^2)), interpolated linearly in r, E_avg with it (linear in the table, so still exact).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from workers.render.microfacet import single_scattering_albedo

COSINES = np.linspace(0.0, 1.0, 65) ** 2
ROUGHNESSES = np.linspace(0.0, 1.0, 33)  # 2-D table nodes, perceptual roughness
QUADRATURE_NODES = 24  # Gauss-Legendre per axis of the visible-normal sampler's square


def cosine_weighted_mean(table: np.ndarray) -> np.ndarray:
    """2 int E(mu) mu dmu of the linear interpolant of `table` (..., len(COSINES)) over COSINES."""
    x, w = np.polynomial.legendre.leggauss(2)
    a, b = COSINES[:-1], COSINES[1:]
    mu = 0.5 * (a + b) + 0.5 * (b - a) * x[:, None]  # (2, intervals)
    t = (mu - a) / (b - a)
    values = table[..., None, :-1] * (1.0 - t) + table[..., None, 1:] * t
    return 2.0 * np.sum(w[:, None] * 0.5 * (b - a) * mu * values, axis=(-2, -1))


def _albedo_at(alpha: float, eta: float) -> np.ndarray:
    return single_scattering_albedo(
        alpha, eta, np.maximum(COSINES, 1e-6), refract=False, nodes=QUADRATURE_NODES
    )


@dataclass(frozen=True)
class SpecularAlbedo:
    """E_s per cosine (COSINES), per roughness row for the 2-D table; E_avg per row."""

    table: np.ndarray  # (len(COSINES),) or (len(ROUGHNESSES), len(COSINES))
    average: np.ndarray  # () or (len(ROUGHNESSES),)

    def at(self, cos: np.ndarray, roughness: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """E_s(|cos|) and E_avg per row; `roughness` (perceptual) selects rows of the 2-D table."""
        mu = np.clip(np.abs(cos), 0.0, 1.0)
        if roughness is None:
            return np.interp(mu, COSINES, self.table), np.full(len(mu), float(self.average))
        r = np.clip(roughness, 0.0, 1.0) * (len(ROUGHNESSES) - 1)
        i = np.minimum(r.astype(np.int64), len(ROUGHNESSES) - 2)
        t = r - i
        j = np.minimum((np.sqrt(mu) * (len(COSINES) - 1)).astype(np.int64), len(COSINES) - 2)
        s = (mu - COSINES[j]) / (COSINES[j + 1] - COSINES[j])
        lo = self.table[i, j] * (1.0 - s) + self.table[i, j + 1] * s
        hi = self.table[i + 1, j] * (1.0 - s) + self.table[i + 1, j + 1] * s
        return lo * (1.0 - t) + hi * t, self.average[i] * (1.0 - t) + self.average[i + 1] * t


@lru_cache(maxsize=256)
def specular_albedo(alpha: float, eta: float) -> SpecularAlbedo:
    table = _albedo_at(alpha, eta)
    return SpecularAlbedo(table, cosine_weighted_mean(table))


@lru_cache(maxsize=16)
def specular_albedo_over_roughness(eta: float, alpha_floor: float) -> SpecularAlbedo:
    table = np.stack([_albedo_at(max(alpha_floor, r * r), eta) for r in ROUGHNESSES])
    return SpecularAlbedo(table, cosine_weighted_mean(table))
