"""Lambertian reflection: f = base / pi, sampled cosine-weighted (weight = base)."""

from __future__ import annotations

import numpy as np

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, register_material
from workers.render.sampling import INV_PI, square_to_cosine_hemisphere
from workers.scene import spec


@register_material("diffuse")
class Diffuse(BSDF):
    def parameters(self, material: spec.Diffuse) -> MaterialParameters:
        return MaterialParameters(base=material.reflectance, roughness=1.0)

    def eval(self, s: SurfaceBatch, wo, wi):
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        cos_i = np.where(valid, wi[:, 2], 0.0)
        return s.base * (cos_i * INV_PI)[:, None], cos_i * INV_PI

    def sample(self, s: SurfaceBatch, wo, u, uc):
        wi = square_to_cosine_hemisphere(u)
        valid = wo[:, 2] > 0
        return wi, s.base * valid[:, None], np.where(valid, wi[:, 2] * INV_PI, 0.0), np.zeros(len(wo), bool)
