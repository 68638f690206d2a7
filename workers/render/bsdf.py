"""Vectorised BSDFs in the local shading frame (z = normal), for batches mixing material kinds.

Conventions: `wo` points to the camera (or previous vertex), `wi` towards the light; both unit.
`eval` returns f(wo, wi) * |cos(wi)| and the solid-angle pdf of `sample` producing wi; delta
lobes are never returned by `eval`. `sample` returns wi, the weight f |cos| / pdf (what a path's
throughput is multiplied by), the pdf (0 for delta lobes) and a delta flag. Transmission carries
the 1/eta^2 radiance scaling. Non-dielectric surfaces are two-sided: the caller flips the frame so
wo.z > 0; dielectrics see both sides and use the sign of wo.z to know which side they are on.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from workers.render.microfacet import (
    ALPHA_MIN,
    fresnel_dielectric,
    ggx_d,
    reflect,
    sample_visible_normal,
    smith_g1,
    visible_normal_pdf,
)
from workers.render.sampling import INV_PI, normalize, square_to_cosine_hemisphere


class Kind(IntEnum):
    DIFFUSE = 0
    CONDUCTOR = 1
    PLASTIC = 2
    DIELECTRIC = 3


@dataclass
class SurfaceBatch:
    """Material parameters at N shading points."""

    kind: np.ndarray  # (N,) int8 Kind
    base: np.ndarray  # (N, 3): diffuse reflectance, or conductor specular colour
    alpha: np.ndarray  # (N,) GGX alpha; 0 means perfectly smooth
    ior: np.ndarray  # (N,) interior over exterior

    def take(self, idx: np.ndarray) -> SurfaceBatch:
        return SurfaceBatch(self.kind[idx], self.base[idx], self.alpha[idx], self.ior[idx])

    @property
    def is_delta(self) -> np.ndarray:
        """Surfaces with only delta lobes, for which next-event estimation is pointless."""
        smooth = self.alpha <= 0
        return smooth & ((self.kind == Kind.CONDUCTOR) | (self.kind == Kind.DIELECTRIC))


def _alpha(a: np.ndarray) -> np.ndarray:
    return np.maximum(a, ALPHA_MIN)


# --------------------------------------------------------------------------- diffuse


def _diffuse_eval(s: SurfaceBatch, wo, wi):
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    cos_i = np.where(valid, wi[:, 2], 0.0)
    return s.base * (cos_i * INV_PI)[:, None], cos_i * INV_PI


def _diffuse_sample(s: SurfaceBatch, wo, u, _uc):
    wi = square_to_cosine_hemisphere(u)
    valid = wo[:, 2] > 0
    return wi, s.base * valid[:, None], np.where(valid, wi[:, 2] * INV_PI, 0.0), np.zeros(len(wo), bool)


# --------------------------------------------------------------------------- conductor


def _conductor_eval(s: SurfaceBatch, wo, wi):
    a = _alpha(s.alpha)
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0) & (s.alpha > 0)
    h = normalize(wo + wi)
    d = ggx_d(h, a)
    g = smith_g1(wo, h, a) * smith_g1(wi, h, a)
    f_cos = d * g / (4.0 * np.maximum(wo[:, 2], 1e-300))
    wo_h = np.einsum("ij,ij->i", wo, h)
    pdf = visible_normal_pdf(wo, h, a) / np.maximum(4.0 * wo_h, 1e-300)
    return s.base * np.where(valid, f_cos, 0.0)[:, None], np.where(valid, pdf, 0.0)


def _conductor_sample(s: SurfaceBatch, wo, u, _uc):
    a = _alpha(s.alpha)
    smooth = s.alpha <= 0
    m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo, a, u))
    wi = reflect(wo, m)
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    g1 = np.where(smooth, 1.0, smith_g1(wi, m, a))
    wo_m = np.einsum("ij,ij->i", wo, m)
    pdf = np.where(smooth, 0.0, visible_normal_pdf(wo, m, a) / np.maximum(4.0 * wo_m, 1e-300))
    weight = s.base * np.where(valid, g1, 0.0)[:, None]
    return wi, weight, np.where(valid, pdf, 0.0), smooth


# --------------------------------------------------------------------------- plastic


def _plastic_spec_probability(s: SurfaceBatch, wo) -> np.ndarray:
    f_o, _, _ = fresnel_dielectric(np.abs(wo[:, 2]), s.ior)
    diffuse_weight = (1.0 - f_o) * s.base.mean(axis=1)
    return np.clip(f_o / np.maximum(f_o + diffuse_weight, 1e-12), 0.05, 1.0)


def _plastic_diffuse_f(s: SurfaceBatch, wo, wi) -> np.ndarray:
    f_o, _, _ = fresnel_dielectric(np.abs(wo[:, 2]), s.ior)
    f_i, _, _ = fresnel_dielectric(np.abs(wi[:, 2]), s.ior)
    return s.base * ((1.0 - f_o) * (1.0 - f_i) * INV_PI)[:, None]


def _plastic_spec_eval(s: SurfaceBatch, wo, wi):
    """Rough coat: f*cos and its VNDF pdf (zero for the smooth coat, which is delta)."""
    a = _alpha(s.alpha)
    h = normalize(wo + wi)
    wo_h = np.einsum("ij,ij->i", wo, h)
    f, _, _ = fresnel_dielectric(wo_h, s.ior)
    g = smith_g1(wo, h, a) * smith_g1(wi, h, a)
    f_cos = f * ggx_d(h, a) * g / (4.0 * np.maximum(wo[:, 2], 1e-300))
    pdf = visible_normal_pdf(wo, h, a) / np.maximum(4.0 * wo_h, 1e-300)
    rough = s.alpha > 0
    return np.where(rough, f_cos, 0.0), np.where(rough, pdf, 0.0)


def _plastic_eval(s: SurfaceBatch, wo, wi):
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    p_spec = _plastic_spec_probability(s, wo)
    spec_f, spec_pdf = _plastic_spec_eval(s, wo, wi)
    f_cos = spec_f[:, None] + _plastic_diffuse_f(s, wo, wi) * wi[:, 2:3]
    pdf = p_spec * spec_pdf + (1.0 - p_spec) * wi[:, 2] * INV_PI
    return f_cos * valid[:, None], np.where(valid, pdf, 0.0)


def _plastic_sample(s: SurfaceBatch, wo, u, uc):
    a = _alpha(s.alpha)
    smooth = s.alpha <= 0
    p_spec = _plastic_spec_probability(s, wo)
    choose_spec = uc < p_spec
    m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo, a, u))
    wi = np.where(choose_spec[:, None], reflect(wo, m), square_to_cosine_hemisphere(u))
    valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
    delta = smooth & choose_spec
    # Smooth coat, specular chosen: the delta lobe alone, F / p_spec.
    f_o, _, _ = fresnel_dielectric(wo[:, 2], s.ior)
    delta_weight = (f_o / p_spec)[:, None] * np.ones((1, 3))
    # Otherwise the one-sample MIS mixture of both lobes.
    f_cos, pdf = _plastic_eval(s, wo, wi)
    mixture_weight = f_cos / np.maximum(pdf, 1e-300)[:, None]
    weight = np.where(delta[:, None], delta_weight, mixture_weight) * valid[:, None]
    return wi, weight, np.where(valid & ~delta, pdf, 0.0), delta


# --------------------------------------------------------------------------- dielectric


def _dielectric_frame(s: SurfaceBatch, wo):
    """Mirror the problem so wo is in the upper hemisphere; eta is then (far side) / (wo's side)."""
    side = np.where(wo[:, 2] >= 0, 1.0, -1.0)
    eta = np.where(side > 0, s.ior, 1.0 / s.ior)
    return side, eta


def _dielectric_eval(s: SurfaceBatch, wo, wi):
    a = _alpha(s.alpha)
    side, eta = _dielectric_frame(s, wo)
    wo_f, wi_f = wo * side[:, None], wi * side[:, None]
    reflection = wi_f[:, 2] > 0
    h = np.where(reflection[:, None], wo_f + wi_f, wo_f + eta[:, None] * wi_f)
    h = normalize(h) * np.where(h[:, 2] < 0, -1.0, 1.0)[:, None]
    wo_h = np.einsum("ij,ij->i", wo_f, h)
    wi_h = np.einsum("ij,ij->i", wi_f, h)
    f, _, _ = fresnel_dielectric(wo_h, np.ones_like(eta) * eta)
    d = ggx_d(h, a)
    g = smith_g1(wo_f, h, a) * smith_g1(wi_f, h, a)
    pdf_m = visible_normal_pdf(wo_f, h, a)
    cos_o = np.maximum(wo_f[:, 2], 1e-300)
    denom = np.maximum((wo_h + eta * wi_h) ** 2, 1e-300)
    r_fcos = f * d * g / (4.0 * cos_o)
    r_pdf = f * pdf_m / np.maximum(4.0 * wo_h, 1e-300)
    t_fcos = np.abs(wi_h * wo_h) * (1.0 - f) * g * d / (cos_o * denom)
    t_pdf = (1.0 - f) * pdf_m * eta * eta * np.abs(wi_h) / denom
    valid = (s.alpha > 0) & (wo_h > 0) & np.where(reflection, wi_h > 0, wi_h < 0) & (wo_f[:, 2] > 0)
    f_cos = np.where(reflection, r_fcos, t_fcos)
    pdf = np.where(reflection, r_pdf, t_pdf)
    return np.where(valid, f_cos, 0.0)[:, None] * np.ones((1, 3)), np.where(valid, pdf, 0.0)


def _dielectric_sample(s: SurfaceBatch, wo, u, uc):
    a = _alpha(s.alpha)
    smooth = s.alpha <= 0
    side, eta = _dielectric_frame(s, wo)
    wo_f = wo * side[:, None]
    m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo_f, a, u))
    wo_m = np.einsum("ij,ij->i", wo_f, m)
    f, cos_t, eta_ti = fresnel_dielectric(wo_m, eta)
    choose_r = uc < f
    wi_r = reflect(wo_f, m)
    wi_t = (eta_ti * wo_m + cos_t)[:, None] * m - eta_ti[:, None] * wo_f
    wi_f = np.where(choose_r[:, None], wi_r, normalize(wi_t))
    valid = np.where(choose_r, wi_f[:, 2] > 0, wi_f[:, 2] < 0) & (wo_m > 0)
    g1 = np.where(smooth, 1.0, smith_g1(wi_f, m, a))
    weight = g1 * np.where(choose_r, 1.0, eta_ti * eta_ti)
    _, pdf = _dielectric_eval(s, wo, wi_f * side[:, None])
    pdf = np.where(smooth, 0.0, pdf)
    return (
        wi_f * side[:, None],
        (weight * valid)[:, None] * np.ones((1, 3)),
        np.where(valid, pdf, 0.0),
        smooth,
    )


_EVAL = {
    Kind.DIFFUSE: _diffuse_eval,
    Kind.CONDUCTOR: _conductor_eval,
    Kind.PLASTIC: _plastic_eval,
    Kind.DIELECTRIC: _dielectric_eval,
}
_SAMPLE = {
    Kind.DIFFUSE: _diffuse_sample,
    Kind.CONDUCTOR: _conductor_sample,
    Kind.PLASTIC: _plastic_sample,
    Kind.DIELECTRIC: _dielectric_sample,
}


def _groups(kind: np.ndarray):
    """(kind, indices) for each material kind present; a single kind avoids any gather."""
    present = np.unique(kind)
    if len(present) == 1:
        yield Kind(int(present[0])), None
        return
    for k in present:
        yield Kind(int(k)), np.flatnonzero(kind == k)


def eval_bsdf(s: SurfaceBatch, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f(wo, wi) |cos wi| (N, 3) and the pdf of sampling wi (N,)."""
    n = len(wo)
    f_cos, pdf = np.zeros((n, 3)), np.zeros(n)
    for kind, idx in _groups(s.kind):
        if idx is None:
            return _EVAL[kind](s, wo, wi)
        f_cos[idx], pdf[idx] = _EVAL[kind](s.take(idx), wo[idx], wi[idx])
    return f_cos, pdf


def sample_bsdf(s: SurfaceBatch, wo: np.ndarray, u: np.ndarray, uc: np.ndarray):
    """Sample wi given wo, two uniforms `u` (N, 2) and a lobe-selection uniform `uc` (N,).

    Returns (wi, weight (N, 3), pdf (N,), delta (N,) bool); weight is zero for invalid samples.
    """
    n = len(wo)
    wi, weight, pdf, delta = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, bool)
    for kind, idx in _groups(s.kind):
        if idx is None:
            return _SAMPLE[kind](s, wo, u, uc)
        wi[idx], weight[idx], pdf[idx], delta[idx] = _SAMPLE[kind](s.take(idx), wo[idx], u[idx], uc[idx])
    return wi, weight, pdf, delta
