"""Lambertian reflection: f = base / pi, sampled cosine-weighted (weight = base)."""

from __future__ import annotations

from workers.render.bsdf import CompiledBSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.jit import njit
from workers.render.kernels import INV_PI, cosine_hemisphere
from workers.scene.format import spec


@register_material("diffuse")
class Diffuse(CompiledBSDF):
    def parameters(self, material: spec.Diffuse) -> MaterialParameters:
        return MaterialParameters(base=material.reflectance, roughness=1.0)

    def eval_kernel(self, s: SurfaceBatch, wo, wi, rows, out):
        _eval(rows, *contiguous(s.base, wo, wi), *out)

    def sample_kernel(self, s: SurfaceBatch, wo, u, uc, rows, out):
        _sample(rows, *contiguous(s.base, wo, u), *out[:3])


@njit(cache=True, nogil=True, fastmath=False)
def _eval(rows, base, wo, wi, f_cos, pdf):
    for i in rows:
        if wo[i, 2] > 0 and wi[i, 2] > 0:
            pdf[i] = wi[i, 2] * INV_PI
            for c in range(3):
                f_cos[i, c] = base[i, c] * pdf[i]


@njit(cache=True, nogil=True, fastmath=False)
def _sample(rows, base, wo, u, wi, weight, pdf):
    for i in rows:
        wi[i, 0], wi[i, 1], wi[i, 2] = cosine_hemisphere(u[i, 0], u[i, 1])
        if wo[i, 2] > 0:
            pdf[i] = wi[i, 2] * INV_PI
            for c in range(3):
                weight[i, c] = base[i, c]
