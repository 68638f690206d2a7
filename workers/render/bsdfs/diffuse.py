"""Lambertian reflection: f = base / pi, sampled cosine-weighted (weight = base)."""

from __future__ import annotations

import numpy as np
from numba import njit

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.kernels import INV_PI, cosine_hemisphere
from workers.scene import spec


@register_material("diffuse")
class Diffuse(BSDF):
    def parameters(self, material: spec.Diffuse) -> MaterialParameters:
        return MaterialParameters(base=material.reflectance, roughness=1.0)

    def eval(self, s: SurfaceBatch, wo, wi):
        return _eval(*contiguous(s.base, wo, wi))

    def sample(self, s: SurfaceBatch, wo, u, uc):
        return _sample(*contiguous(s.base, wo, u))


@njit(cache=True, nogil=True, fastmath=False)
def _eval(base, wo, wi):
    n = len(wo)
    f_cos, pdf = np.zeros((n, 3)), np.zeros(n)
    for i in range(n):
        if wo[i, 2] > 0 and wi[i, 2] > 0:
            pdf[i] = wi[i, 2] * INV_PI
            for c in range(3):
                f_cos[i, c] = base[i, c] * pdf[i]
    return f_cos, pdf


@njit(cache=True, nogil=True, fastmath=False)
def _sample(base, wo, u):
    n = len(wo)
    wi, weight, pdf = np.empty((n, 3)), np.zeros((n, 3)), np.zeros(n)
    for i in range(n):
        wi[i, 0], wi[i, 1], wi[i, 2] = cosine_hemisphere(u[i, 0], u[i, 1])
        if wo[i, 2] > 0:
            pdf[i] = wi[i, 2] * INV_PI
            weight[i] = base[i]
    return wi, weight, pdf, np.zeros(n, np.bool_)
