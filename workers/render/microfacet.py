"""GGX microfacet distribution with Smith masking and visible-normal sampling (Heitz 2018).

All vectors are in the local shading frame (z = normal). alpha is clamped to ALPHA_MIN so
that roughness -> 0 stays finite; exactly 0 is handled by the callers as a delta lobe.
"""

from __future__ import annotations

import numpy as np

from workers.render.sampling import safe_sqrt

ALPHA_MIN = 1e-4


def ggx_d(m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Normal distribution D(m); zero below the surface."""
    a2 = alpha * alpha
    cos2 = m[:, 2] ** 2
    denom = cos2 * (a2 - 1.0) + 1.0
    return np.where(m[:, 2] > 0, a2 / (np.pi * np.maximum(denom * denom, 1e-300)), 0.0)


def smith_g1(v: np.ndarray, m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Smith masking for GGX; zero when v sees the back of the microfacet."""
    cos2 = v[:, 2] ** 2
    tan2 = np.maximum(1.0 - cos2, 0.0) / np.maximum(cos2, 1e-300)
    g = 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * tan2))
    valid = (np.einsum("ij,ij->i", v, m) * v[:, 2]) > 0
    return np.where(valid, g, 0.0)


def sample_visible_normal(wo: np.ndarray, alpha: np.ndarray, u: np.ndarray) -> np.ndarray:
    """A microfacet normal distributed as D_wo(m) = G1(wo) max(0, wo.m) D(m) / cos(wo); wo.z > 0."""
    vh = np.stack([alpha * wo[:, 0], alpha * wo[:, 1], wo[:, 2]], axis=1)
    vh /= np.maximum(np.linalg.norm(vh, axis=1, keepdims=True), 1e-300)
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = 1.0 / np.sqrt(np.maximum(lensq, 1e-300))
    t1 = np.where(
        (lensq > 1e-14)[:, None],
        np.stack([-vh[:, 1] * inv, vh[:, 0] * inv, np.zeros_like(lensq)], axis=1),
        np.array([1.0, 0.0, 0.0]),
    )
    t2 = np.cross(vh, t1)
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    p1 = r * np.cos(phi)
    p2 = r * np.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * safe_sqrt(1.0 - p1 * p1) + s * p2
    p3 = safe_sqrt(1.0 - p1 * p1 - p2 * p2)
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    m = np.stack([alpha * nh[:, 0], alpha * nh[:, 1], np.maximum(nh[:, 2], 1e-12)], axis=1)
    return m / np.linalg.norm(m, axis=1, keepdims=True)


def visible_normal_pdf(wo: np.ndarray, m: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Density of `sample_visible_normal` over microfacet normals (solid angle of m)."""
    cos_o = np.abs(wo[:, 2])
    wo_m = np.einsum("ij,ij->i", wo, m)
    return smith_g1(wo, m, alpha) * np.maximum(wo_m, 0.0) * ggx_d(m, alpha) / np.maximum(cos_o, 1e-300)


def fresnel_dielectric(cos_i: np.ndarray, eta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unpolarised Fresnel reflectance for light arriving with cosine `cos_i` (sign says the side).

    `eta` is interior over exterior IOR. Returns (F, cos_t signed opposite to cos_i, eta_ti),
    where eta_ti is the relative IOR across the interface in the direction of travel.
    """
    outside = cos_i >= 0
    eta_it = np.where(outside, eta, 1.0 / eta)
    eta_ti = 1.0 / eta_it
    cos_i_abs = np.abs(cos_i)
    cos_t2 = 1.0 - eta_ti * eta_ti * (1.0 - cos_i_abs * cos_i_abs)
    tir = cos_t2 <= 0
    cos_t = safe_sqrt(cos_t2)
    rs = (cos_i_abs - eta_it * cos_t) / np.maximum(cos_i_abs + eta_it * cos_t, 1e-300)
    rp = (eta_it * cos_i_abs - cos_t) / np.maximum(eta_it * cos_i_abs + cos_t, 1e-300)
    f = np.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))
    cos_t_signed = np.where(outside, -cos_t, cos_t)
    return np.clip(f, 0.0, 1.0), cos_t_signed, eta_ti


def reflect(wo: np.ndarray, m: np.ndarray) -> np.ndarray:
    return 2.0 * np.einsum("ij,ij->i", wo, m)[:, None] * m - wo


def single_scattering_albedo(alpha: float, eta: float, cosines: np.ndarray, *, refract: bool, nodes: int):
    """Per cosine, E over visible normals m of G1(w, m) times F (reflection) or 1 - F (refraction), w the
    reflected or refracted direction: the energy a single scattering sends back up or through. Gauss-Legendre
    over the sampler's unit square; `eta` is the far side's index over the near side's."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    u = np.stack(np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5), axis=-1).reshape(-1, 2)
    weights = 0.25 * np.outer(w, w).ravel()
    wi = np.repeat(np.stack([np.sqrt(1.0 - cosines**2), np.zeros_like(cosines), cosines], axis=1), len(u), 0)
    u = np.tile(u, (len(cosines), 1))
    a = np.full(len(u), alpha)
    m = sample_visible_normal(wi, a, u)
    wi_m = np.einsum("ij,ij->i", wi, m)
    f, cos_t, eta_ti = fresnel_dielectric(wi_m, np.full(len(u), eta))
    if refract:
        out = (eta_ti * wi_m + cos_t)[:, None] * m - eta_ti[:, None] * wi
        energy = np.where(out[:, 2] < 0, smith_g1(out, m, a) * (1.0 - f), 0.0)
    else:
        out = reflect(wi, m)
        energy = np.where(out[:, 2] > 0, smith_g1(out, m, a) * f, 0.0)
    return (energy * np.tile(weights, len(cosines))).reshape(len(cosines), -1).sum(axis=1)
