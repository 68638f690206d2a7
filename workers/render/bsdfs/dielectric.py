"""Glass: a smooth (delta) or GGX-rough interface between the outside and an interior of index `ior`
(Walter et al. 2007), seen from both sides; transmission carries the 1/eta^2 radiance scaling."""

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
from workers.render.sampling import normalize
from workers.scene import spec


def _frame(s: SurfaceBatch, wo):
    """Mirror the problem so wo is in the upper hemisphere; eta is then (far side) / (wo's side)."""
    side = np.where(wo[:, 2] >= 0, 1.0, -1.0)
    eta = np.where(side > 0, s.ior, 1.0 / s.ior)
    return side, eta


@register_material("dielectric")
class Dielectric(BSDF):
    two_sided = False
    delta_when_smooth = True

    def parameters(self, material: spec.Dielectric) -> MaterialParameters:
        return MaterialParameters(alpha=material.roughness, ior=material.ior, roughness=material.roughness)

    def eval(self, s: SurfaceBatch, wo, wi):
        a = np.maximum(s.alpha, ALPHA_MIN)
        side, eta = _frame(s, wo)
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

    def sample(self, s: SurfaceBatch, wo, u, uc):
        a = np.maximum(s.alpha, ALPHA_MIN)
        smooth = s.alpha <= 0
        side, eta = _frame(s, wo)
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
        _, pdf = self.eval(s, wo, wi_f * side[:, None])
        pdf = np.where(smooth, 0.0, pdf)
        return (
            wi_f * side[:, None],
            (weight * valid)[:, None] * np.ones((1, 3)),
            np.where(valid, pdf, 0.0),
            smooth,
        )
