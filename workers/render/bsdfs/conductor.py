"""GGX metal whose Fresnel term is the specular colour (Mitsuba's `conductor` with `material: none`):
f cos = F D G / (4 cos_o), sampled by visible normals (Heitz 2018), the weight then F G1(wi)."""

from __future__ import annotations

import numpy as np
from numba import njit

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.kernels import (
    ALPHA_MIN,
    ggx_d,
    normalized,
    reflect,
    smith_g1,
    visible_normal,
    visible_normal_pdf,
)
from workers.scene import spec


@register_material("conductor")
class Conductor(BSDF):
    delta_when_smooth = True

    def parameters(self, material: spec.Conductor) -> MaterialParameters:
        return MaterialParameters(
            base=material.specular, alpha=material.roughness, roughness=material.roughness
        )

    def eval(self, s: SurfaceBatch, wo, wi):
        return _eval(*contiguous(s.base, s.alpha, wo, wi))

    def sample(self, s: SurfaceBatch, wo, u, uc):
        return _sample(*contiguous(s.base, s.alpha, wo, u))


@njit(cache=True, nogil=True, fastmath=False)
def _eval(base, alpha, wo, wi):
    n = len(wo)
    f_cos, pdf = np.zeros((n, 3)), np.zeros(n)
    for i in range(n):
        if not (wo[i, 2] > 0 and wi[i, 2] > 0 and alpha[i] > 0):
            continue
        a = max(alpha[i], ALPHA_MIN)
        hx, hy, hz = normalized(wo[i, 0] + wi[i, 0], wo[i, 1] + wi[i, 1], wo[i, 2] + wi[i, 2])
        wo_h = wo[i, 0] * hx + wo[i, 1] * hy + wo[i, 2] * hz
        wi_h = wi[i, 0] * hx + wi[i, 1] * hy + wi[i, 2] * hz
        g = smith_g1(wo[i, 2], wo_h, a) * smith_g1(wi[i, 2], wi_h, a)
        value = ggx_d(hz, a) * g / (4.0 * max(wo[i, 2], 1e-300))
        for c in range(3):
            f_cos[i, c] = base[i, c] * value
        pdf[i] = visible_normal_pdf(wo[i, 2], wo_h, hz, a) / max(4.0 * wo_h, 1e-300)
    return f_cos, pdf


@njit(cache=True, nogil=True, fastmath=False)
def _sample(base, alpha, wo, u):
    n = len(wo)
    wi, weight, pdf, delta = np.empty((n, 3)), np.zeros((n, 3)), np.zeros(n), np.empty(n, np.bool_)
    for i in range(n):
        a = max(alpha[i], ALPHA_MIN)
        smooth = alpha[i] <= 0
        delta[i] = smooth
        if smooth:
            mx, my, mz = 0.0, 0.0, 1.0
        else:
            mx, my, mz = visible_normal(wo[i, 0], wo[i, 1], wo[i, 2], a, u[i, 0], u[i, 1])
        wx, wy, wz = reflect(wo[i, 0], wo[i, 1], wo[i, 2], mx, my, mz)
        wi[i, 0], wi[i, 1], wi[i, 2] = wx, wy, wz
        if not (wo[i, 2] > 0 and wz > 0):
            continue
        g1 = 1.0 if smooth else smith_g1(wz, wx * mx + wy * my + wz * mz, a)
        for c in range(3):
            weight[i, c] = base[i, c] * g1
        if not smooth:
            wo_m = wo[i, 0] * mx + wo[i, 1] * my + wo[i, 2] * mz
            pdf[i] = visible_normal_pdf(wo[i, 2], wo_m, mz, a) / max(4.0 * wo_m, 1e-300)
    return wi, weight, pdf, delta
