"""Glass: a smooth (delta) or GGX-rough interface between the outside and an interior of index `ior`
(Walter et al. 2007), seen from both sides; transmission carries the 1/eta^2 radiance scaling."""

from __future__ import annotations

from workers.render.bsdf import CompiledBSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.jit import njit
from workers.render.kernels import (
    ALPHA_MIN,
    fresnel_dielectric,
    ggx_d,
    normalized,
    reflect,
    scalar,
    smith_g1,
    visible_normal,
    visible_normal_pdf,
)
from workers.scene.format import spec


@register_material("dielectric")
class Dielectric(CompiledBSDF):
    two_sided = False

    def parameters(self, material: spec.Dielectric) -> MaterialParameters:
        return MaterialParameters(alpha=material.roughness, ior=material.ior, roughness=material.roughness)

    def eval_kernel(self, s: SurfaceBatch, wo, wi, rows, out):
        _eval(rows, *contiguous(s.alpha, s.ior, wo, wi), *out)

    def sample_kernel(self, s: SurfaceBatch, wo, u, uc, rows, out):
        _sample(rows, *contiguous(s.alpha, s.ior, wo, u, uc), *out)


@scalar
def _eval_one(alpha, ior, wo, wi):
    """(f |cos wi|, pdf) of one rough interface for rows wo, wi. The problem is mirrored so wo is in the upper
    hemisphere; eta is then (far side) / (wo's side)."""
    if alpha <= 0:
        return 0.0, 0.0
    a = max(alpha, ALPHA_MIN)
    side = 1.0 if wo[2] >= 0 else -1.0
    eta = ior if side > 0 else 1.0 / ior
    ox, oy, oz, ix, iy, iz = (
        wo[0] * side,
        wo[1] * side,
        wo[2] * side,
        wi[0] * side,
        wi[1] * side,
        wi[2] * side,
    )
    reflection = iz > 0
    scale = 1.0 if reflection else eta
    hx, hy, hz = ox + scale * ix, oy + scale * iy, oz + scale * iz
    flip = -1.0 if hz < 0 else 1.0
    hx, hy, hz = normalized(hx, hy, hz)
    hx, hy, hz = hx * flip, hy * flip, hz * flip
    wo_h = ox * hx + oy * hy + oz * hz
    wi_h = ix * hx + iy * hy + iz * hz
    if not (wo_h > 0 and oz > 0 and ((wi_h > 0) if reflection else (wi_h < 0))):
        return 0.0, 0.0
    f = fresnel_dielectric(wo_h, eta)[0]
    d = ggx_d(hz, a)
    g = smith_g1(oz, wo_h, a) * smith_g1(iz, wi_h, a)
    pdf_m = visible_normal_pdf(oz, wo_h, hz, a)
    cos_o = max(oz, 1e-300)
    if reflection:
        return f * d * g / (4.0 * cos_o), f * pdf_m / max(4.0 * wo_h, 1e-300)
    denom = max((wo_h + eta * wi_h) ** 2, 1e-300)
    t_fcos = abs(wi_h * wo_h) * (1.0 - f) * g * d / (cos_o * denom)
    return t_fcos, (1.0 - f) * pdf_m * eta * eta * abs(wi_h) / denom


@njit(cache=True, nogil=True, fastmath=False)
def _eval(rows, alpha, ior, wo, wi, f_cos, pdf):
    for i in rows:
        value, pdf[i] = _eval_one(alpha[i], ior[i], wo[i], wi[i])
        f_cos[i, 0] = f_cos[i, 1] = f_cos[i, 2] = value


@njit(cache=True, nogil=True, fastmath=False)
def _sample(rows, alpha, ior, wo, u, uc, wi, weight, pdf, delta, eta_out):
    for i in rows:
        a = max(alpha[i], ALPHA_MIN)
        smooth = alpha[i] <= 0
        delta[i] = smooth
        side = 1.0 if wo[i, 2] >= 0 else -1.0
        eta = ior[i] if side > 0 else 1.0 / ior[i]
        ox, oy, oz = wo[i, 0] * side, wo[i, 1] * side, wo[i, 2] * side
        if smooth:
            mx, my, mz = 0.0, 0.0, 1.0
        else:
            mx, my, mz = visible_normal(ox, oy, oz, a, u[i, 0], u[i, 1])
        wo_m = ox * mx + oy * my + oz * mz
        f, cos_t, eta_ti = fresnel_dielectric(wo_m, eta)
        choose_r = uc[i] < f
        if choose_r:
            ix, iy, iz = reflect(ox, oy, oz, mx, my, mz)
        else:
            c = eta_ti * wo_m + cos_t
            ix, iy, iz = normalized(c * mx - eta_ti * ox, c * my - eta_ti * oy, c * mz - eta_ti * oz)
        wi[i, 0], wi[i, 1], wi[i, 2] = ix * side, iy * side, iz * side
        if not (((iz > 0) if choose_r else (iz < 0)) and wo_m > 0):
            continue
        g1 = 1.0 if smooth else smith_g1(iz, ix * mx + iy * my + iz * mz, a)
        w = g1 * (1.0 if choose_r else eta_ti * eta_ti)
        weight[i, 0] = weight[i, 1] = weight[i, 2] = w
        if not choose_r:
            eta_out[i] = eta  # far side over wo's side: 1 / eta_ti, whose square the weight divides by
        if not smooth:
            pdf[i] = _eval_one(alpha[i], ior[i], wo[i], wi[i])[1]
