"""A diffuse base under a GGX dielectric coat (energy-conserving by construction).

f = F(wo.h) D G / (4 cos_o cos_i) + base (1 - F(cos_o)) (1 - F(cos_i)) / pi. Sampling picks the coat
with probability F(cos_o) / (F(cos_o) + (1 - F(cos_o)) mean(base)), clamped to [0.05, 1], and weights by
the one-sample MIS mixture of both lobes; a smooth coat's specular lobe is delta.
"""

from __future__ import annotations

import numpy as np

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, register_material
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
from workers.scene import spec


def _spec_probability(s: SurfaceBatch, wo) -> np.ndarray:
    f_o, _, _ = fresnel_dielectric(np.abs(wo[:, 2]), s.ior)
    diffuse_weight = (1.0 - f_o) * s.base.mean(axis=1)
    return np.clip(f_o / np.maximum(f_o + diffuse_weight, 1e-12), 0.05, 1.0)


def _diffuse_f(s: SurfaceBatch, wo, wi) -> np.ndarray:
    f_o, _, _ = fresnel_dielectric(np.abs(wo[:, 2]), s.ior)
    f_i, _, _ = fresnel_dielectric(np.abs(wi[:, 2]), s.ior)
    return s.base * ((1.0 - f_o) * (1.0 - f_i) * INV_PI)[:, None]


def _coat_eval(s: SurfaceBatch, wo, wi):
    """Rough coat: f*cos and its VNDF pdf (zero for the smooth coat, which is delta)."""
    a = np.maximum(s.alpha, ALPHA_MIN)
    h = normalize(wo + wi)
    wo_h = np.einsum("ij,ij->i", wo, h)
    f, _, _ = fresnel_dielectric(wo_h, s.ior)
    g = smith_g1(wo, h, a) * smith_g1(wi, h, a)
    f_cos = f * ggx_d(h, a) * g / (4.0 * np.maximum(wo[:, 2], 1e-300))
    pdf = visible_normal_pdf(wo, h, a) / np.maximum(4.0 * wo_h, 1e-300)
    rough = s.alpha > 0
    return np.where(rough, f_cos, 0.0), np.where(rough, pdf, 0.0)


@register_material("plastic")
class Plastic(BSDF):
    def parameters(self, material: spec.Plastic) -> MaterialParameters:
        return MaterialParameters(
            base=material.diffuse, alpha=material.roughness, ior=material.ior, roughness=material.roughness
        )

    def eval(self, s: SurfaceBatch, wo, wi):
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        p_spec = _spec_probability(s, wo)
        spec_f, spec_pdf = _coat_eval(s, wo, wi)
        f_cos = spec_f[:, None] + _diffuse_f(s, wo, wi) * wi[:, 2:3]
        pdf = p_spec * spec_pdf + (1.0 - p_spec) * wi[:, 2] * INV_PI
        return f_cos * valid[:, None], np.where(valid, pdf, 0.0)

    def sample(self, s: SurfaceBatch, wo, u, uc):
        a = np.maximum(s.alpha, ALPHA_MIN)
        smooth = s.alpha <= 0
        p_spec = _spec_probability(s, wo)
        choose_spec = uc < p_spec
        m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo, a, u))
        wi = np.where(choose_spec[:, None], reflect(wo, m), square_to_cosine_hemisphere(u))
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        delta = smooth & choose_spec
        # Smooth coat, specular chosen: the delta lobe alone, F / p_spec.
        f_o, _, _ = fresnel_dielectric(wo[:, 2], s.ior)
        delta_weight = (f_o / p_spec)[:, None] * np.ones((1, 3))
        # Otherwise the one-sample MIS mixture of both lobes.
        f_cos, pdf = self.eval(s, wo, wi)
        mixture_weight = f_cos / np.maximum(pdf, 1e-300)[:, None]
        weight = np.where(delta[:, None], delta_weight, mixture_weight) * valid[:, None]
        return wi, weight, np.where(valid & ~delta, pdf, 0.0), delta
