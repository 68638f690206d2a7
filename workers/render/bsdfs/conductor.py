"""GGX metal whose Fresnel term is the specular colour (Mitsuba's `conductor` with `material: none`):
f cos = F D G / (4 cos_o), sampled by visible normals (Heitz 2018), the weight then F G1(wi)."""

from __future__ import annotations

from workers.render.bsdf import CompiledBSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.jit import njit
from workers.render.kernels import (
    ALPHA_MIN,
    ggx_d,
    normalized,
    reflect,
    smith_g1,
    visible_normal,
    visible_normal_pdf,
)
from workers.scene.format import spec


@register_material("conductor")
class Conductor(CompiledBSDF):
    def parameters(self, material: spec.Conductor) -> MaterialParameters:
        return MaterialParameters(
            base=material.specular, alpha=material.roughness, roughness=material.roughness
        )

    def eval_kernel(self, s: SurfaceBatch, wo, wi, rows, out):
        _eval(rows, *contiguous(s.base, s.alpha, wo, wi), *out)

    def sample_kernel(self, s: SurfaceBatch, wo, u, uc, rows, out):
        _sample(rows, *contiguous(s.base, s.alpha, wo, u), *out[:4])  # reflection only: eta stays 1


@njit(cache=True, nogil=True, fastmath=False)
def _eval(rows, base, alpha, wo, wi, f_cos, pdf):
    for i in rows:
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


@njit(cache=True, nogil=True, fastmath=False)
def _sample(rows, base, alpha, wo, u, wi, weight, pdf, delta):
    for i in rows:
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
