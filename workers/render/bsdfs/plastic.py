"""A diffuse base under a smooth or GGX-rough dielectric coat: Mitsuba 3's `plastic` / `roughplastic`
with `nonlinear=false`, which is what the comparisons export it as (tests/support/mitsuba_scene.py).

    f cos = F(wo.h) D G / (4 cos_o)                                           the coat (Walter et al. 2007)
          + base / (1 - R_int) / eta^2  T(cos_o) T(cos_i) cos_i / pi         the base seen through it

T(mu) is the coat's transmittance for light arriving from outside at cosine mu, and R_int its reflectance
for diffuse light from inside: light crossing the coat bounces between base and coat, a geometric series
whose base albedo is taken as 1 (`nonlinear=false`), hence 1 / (1 - R_int); 1/eta^2 is the radiance
scaling of leaving the denser coat. A smooth coat has T = 1 - F and R_int = 2 int F_inside(mu) mu dmu, so with
1 - R_int = (1 - R_outside) / eta^2 the base's albedo is exactly base (1 - F(cos_o)). A rough coat's T and
R_int are single-scattering integrals over its visible normals, tabulated per (alpha, eta) as Mitsuba does:
T at 64 evenly spaced cosines (interpolated linearly), R_int as twice the mean of R mu over the same
cosines. That mean underestimates the integral (0.588 against 0.596 for eta = 1.5 near alpha = 0, so a
barely rough coat's base is ~2% darker than a smooth one's); it is kept so that both renderers agree.
Single scattering loses the light a rough coat reflects into itself: over a white base the albedo is
exactly 1 for a smooth coat, ~0.96 at alpha 0.05, ~0.69 at 0.3 and ~0.44 at 0.7 (Mitsuba's too).

Sampling picks the coat with probability (1 - T(cos_o)) / (1 - T(cos_o) + T(cos_o) mean(base)), clamped to
[0.05, 1], and weights by the one-sample MIS mixture of both lobes; a smooth coat's lobe is delta.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from workers.render import kernels as k
from workers.render.bsdf import CompiledBSDF, MaterialParameters, SurfaceBatch, contiguous, register_material
from workers.render.jit import njit
from workers.render.microfacet import fresnel_dielectric, single_scattering_albedo
from workers.scene.format import spec

TABLE_COSINES = np.linspace(0.0, 1.0, 64)  # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES nodes


@dataclass(frozen=True)
class Coat:
    """A coat's transmittance from outside at `TABLE_COSINES` (smooth: None, i.e. 1 - F) and its internal
    reflectance."""

    ior: float
    transmittance_table: np.ndarray | None
    internal_reflectance: float


@lru_cache(maxsize=256)
def coat(alpha: float, ior: float) -> Coat:
    if alpha <= 0:
        # 2 int F_inside(mu) mu dmu: total reflection below the critical cosine mu_c, Gauss-Legendre above.
        mu_c = np.sqrt(1.0 - 1.0 / ior**2)
        x, w = np.polynomial.legendre.leggauss(64)
        mu = mu_c + (1.0 - mu_c) * 0.5 * (x + 1.0)
        f_inside = fresnel_dielectric(-mu, np.full(len(mu), ior))[0]
        return Coat(ior, None, float(mu_c**2 + (1.0 - mu_c) * np.sum(w * f_inside * mu)))
    cosines = np.maximum(TABLE_COSINES, 1e-6)
    table = single_scattering_albedo(alpha, ior, cosines, refract=True, nodes=32)
    inside = single_scattering_albedo(alpha, 1.0 / ior, cosines, refract=False, nodes=64)
    return Coat(ior, table, float(2.0 * np.mean(inside * cosines)))


def _coats(s: SurfaceBatch, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row of the batch the index of its coat (set on `rows`), and per coat its transmittance table and
    internal reflectance; one pass per (alpha, ior) present, as a scene has few of them."""
    index = np.zeros(len(s.alpha), np.int64)
    tables, internal = [], []
    todo = np.zeros(len(s.alpha), bool)
    todo[rows] = True
    while todo.any():
        first = int(np.argmax(todo))
        rows = todo & (s.alpha == s.alpha[first]) & (s.ior == s.ior[first])
        todo &= ~rows
        c = coat(float(s.alpha[first]), float(s.ior[first]))
        index[rows] = len(tables)
        smooth = c.transmittance_table is None  # the kernels compute 1 - F instead
        tables.append(np.zeros(len(TABLE_COSINES)) if smooth else c.transmittance_table)
        internal.append(c.internal_reflectance)
    return index, np.array(tables).reshape(-1, len(TABLE_COSINES)), np.array(internal)


@register_material("plastic")
class Plastic(CompiledBSDF):
    def parameters(self, material: spec.Plastic) -> MaterialParameters:
        return MaterialParameters(
            base=material.diffuse, alpha=material.roughness, ior=material.ior, roughness=material.roughness
        )

    def eval_kernel(self, s: SurfaceBatch, wo, wi, rows, out):
        _eval(rows, *contiguous(s.base, s.alpha, s.ior, wo, wi), *_coats(s, rows), *out)

    def sample_kernel(self, s: SurfaceBatch, wo, u, uc, rows, out):
        _sample(
            rows, *contiguous(s.base, s.alpha, s.ior, wo, u, uc), *_coats(s, rows), *out[:4]
        )  # reflection only: eta stays 1


@k.scalar
def _transmittance(cos, alpha, ior, table):
    """The coat's transmittance at `cos` in [0, 1]: 1 - F when smooth, else the table read linearly."""
    if alpha <= 0:
        return 1.0 - k.fresnel_dielectric(cos, ior)[0]
    x = cos * (len(table) - 1)
    j = min(int(x), len(table) - 2)
    return table[j] + (x - j) * (table[j + 1] - table[j])


@k.scalar
def _spec_probability(t_o, base_mean):
    return min(max((1.0 - t_o) / max(1.0 - t_o + t_o * base_mean, 1e-12), 0.05), 1.0)


@k.scalar
def _eval_one(base, alpha, ior, table, internal, ox, oy, oz, ix, iy, iz, f_cos):
    """Writes f |cos wi| (3) into `f_cos` and returns the pdf, for one row with wo.z, wi.z > 0."""
    cos_o, cos_i = min(oz, 1.0), min(iz, 1.0)
    t_o = _transmittance(cos_o, alpha, ior, table)
    t_i = _transmittance(cos_i, alpha, ior, table)
    spec_f, spec_pdf = 0.0, 0.0
    if alpha > 0:  # the rough coat (Walter et al. 2007); a smooth one is delta
        a = max(alpha, k.ALPHA_MIN)
        hx, hy, hz = k.normalized(ox + ix, oy + iy, oz + iz)
        wo_h = ox * hx + oy * hy + oz * hz
        wi_h = ix * hx + iy * hy + iz * hz
        f = k.fresnel_dielectric(wo_h, ior)[0]
        g = k.smith_g1(oz, wo_h, a) * k.smith_g1(iz, wi_h, a)
        spec_f = f * k.ggx_d(hz, a) * g / (4.0 * max(oz, 1e-300))
        spec_pdf = k.visible_normal_pdf(oz, wo_h, hz, a) / max(4.0 * wo_h, 1e-300)
    diffuse = t_o * t_i * cos_i * k.INV_PI / ((1.0 - internal) * ior * ior)
    for c in range(3):
        f_cos[c] = spec_f + base[c] * diffuse
    p_spec = _spec_probability(t_o, (base[0] + base[1] + base[2]) / 3.0)
    return p_spec * spec_pdf + (1.0 - p_spec) * cos_i * k.INV_PI


@njit(cache=True, nogil=True, fastmath=False)
def _eval(rows, base, alpha, ior, wo, wi, coat_index, tables, internal, f_cos, pdf):
    for i in rows:
        if wo[i, 2] > 0 and wi[i, 2] > 0:
            j = coat_index[i]
            pdf[i] = _eval_one(
                base[i], alpha[i], ior[i], tables[j], internal[j], wo[i, 0], wo[i, 1], wo[i, 2],
                wi[i, 0], wi[i, 1], wi[i, 2], f_cos[i],
            )  # fmt: skip


@njit(cache=True, nogil=True, fastmath=False)
def _sample(rows, base, alpha, ior, wo, u, uc, coat_index, tables, internal, wi, weight, pdf, delta):
    f_cos = np.empty(3)
    for i in rows:
        j = coat_index[i]
        ox, oy, oz = wo[i, 0], wo[i, 1], wo[i, 2]
        t_o = _transmittance(min(max(oz, 0.0), 1.0), alpha[i], ior[i], tables[j])
        p_spec = _spec_probability(t_o, (base[i, 0] + base[i, 1] + base[i, 2]) / 3.0)
        choose_spec = uc[i] < p_spec
        smooth = alpha[i] <= 0
        if choose_spec:
            if smooth:
                mx, my, mz = 0.0, 0.0, 1.0
            else:
                mx, my, mz = k.visible_normal(ox, oy, oz, max(alpha[i], k.ALPHA_MIN), u[i, 0], u[i, 1])
            ix, iy, iz = k.reflect(ox, oy, oz, mx, my, mz)
        else:
            ix, iy, iz = k.cosine_hemisphere(u[i, 0], u[i, 1])
        wi[i, 0], wi[i, 1], wi[i, 2] = ix, iy, iz
        delta[i] = smooth and choose_spec
        if not (oz > 0 and iz > 0):
            continue
        if delta[i]:  # the smooth coat's delta lobe alone: F / p_spec, with F = 1 - T
            weight[i, 0] = weight[i, 1] = weight[i, 2] = (1.0 - t_o) / p_spec
            continue
        # Otherwise the one-sample MIS mixture of both lobes.
        pdf[i] = _eval_one(base[i], alpha[i], ior[i], tables[j], internal[j], ox, oy, oz, ix, iy, iz, f_cos)
        for c in range(3):
            weight[i, c] = f_cos[c] / max(pdf[i], 1e-300)
