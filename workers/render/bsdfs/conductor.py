"""GGX metal whose Fresnel term is the specular colour (Mitsuba's `conductor` with `material: none`):
f cos = F D G / (4 cos_o), sampled by visible normals (Heitz 2018), the weight then F G1(wi)."""

from __future__ import annotations

import numpy as np

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, register_material
from workers.render.microfacet import (
    ALPHA_MIN,
    ggx_d,
    reflect,
    sample_visible_normal,
    smith_g1,
    visible_normal_pdf,
)
from workers.render.sampling import normalize
from workers.scene import spec


@register_material("conductor")
class Conductor(BSDF):
    delta_when_smooth = True

    def parameters(self, material: spec.Conductor) -> MaterialParameters:
        return MaterialParameters(
            base=material.specular, alpha=material.roughness, roughness=material.roughness
        )

    def eval(self, s: SurfaceBatch, wo, wi):
        a = np.maximum(s.alpha, ALPHA_MIN)
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0) & (s.alpha > 0)
        h = normalize(wo + wi)
        d = ggx_d(h, a)
        g = smith_g1(wo, h, a) * smith_g1(wi, h, a)
        f_cos = d * g / (4.0 * np.maximum(wo[:, 2], 1e-300))
        wo_h = np.einsum("ij,ij->i", wo, h)
        pdf = visible_normal_pdf(wo, h, a) / np.maximum(4.0 * wo_h, 1e-300)
        return s.base * np.where(valid, f_cos, 0.0)[:, None], np.where(valid, pdf, 0.0)

    def sample(self, s: SurfaceBatch, wo, u, uc):
        a = np.maximum(s.alpha, ALPHA_MIN)
        smooth = s.alpha <= 0
        m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo, a, u))
        wi = reflect(wo, m)
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        g1 = np.where(smooth, 1.0, smith_g1(wi, m, a))
        wo_m = np.einsum("ij,ij->i", wo, m)
        pdf = np.where(smooth, 0.0, visible_normal_pdf(wo, m, a) / np.maximum(4.0 * wo_m, 1e-300))
        weight = s.base * np.where(valid, g1, 0.0)[:, None]
        return wi, weight, np.where(valid, pdf, 0.0), smooth
