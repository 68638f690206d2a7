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

TABLE_COSINES = np.linspace(0.0, 1.0, 64)  # Mitsuba's MI_ROUGH_TRANSMITTANCE_RES nodes


@dataclass(frozen=True)
class Coat:
    """A coat's transmittance from outside (smooth: None, i.e. 1 - F) and its internal reflectance."""

    ior: float
    transmittance_table: np.ndarray | None
    internal_reflectance: float

    def transmittance(self, cos: np.ndarray) -> np.ndarray:
        if self.transmittance_table is None:
            return 1.0 - fresnel_dielectric(cos, np.full(len(cos), self.ior))[0]
        return np.interp(cos, TABLE_COSINES, self.transmittance_table)


def _visible_normal_average(alpha: float, eta: float, cosines: np.ndarray, *, refract: bool, nodes: int):
    """Per cosine, E over visible normals m of G1(w, m) times F (reflection) or 1 - F (refraction), w the
    reflected or refracted direction: the energy a single scattering sends back up or through. Gauss-Legendre
    over the sampler's unit square; `eta` is the far side's index over the near side's."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    u = np.stack(np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5), axis=-1).reshape(-1, 2)
    weights = 0.25 * np.outer(w, w).ravel()
    wi = np.repeat(np.stack([np.sqrt(1.0 - cosines**2), np.zeros_like(cosines), cosines], axis=1), len(u), 0)
    u = np.tile(u, (len(cosines), 1))
    a = np.full(len(u), alpha)
    m = sample_visible_normal(wi, a, u)
    wi_m = np.einsum("ij,ij->i", wi, m)
    f, cos_t, eta_ti = fresnel_dielectric(wi_m, np.full(len(u), eta))
    if refract:
        out = (eta_ti * wi_m + cos_t)[:, None] * m - eta_ti[:, None] * wi
        energy = np.where(out[:, 2] < 0, smith_g1(out, m, a) * (1.0 - f), 0.0)
    else:
        out = reflect(wi, m)
        energy = np.where(out[:, 2] > 0, smith_g1(out, m, a) * f, 0.0)
    return (energy * np.tile(weights, len(cosines))).reshape(len(cosines), -1).sum(axis=1)


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
    table = _visible_normal_average(alpha, ior, cosines, refract=True, nodes=32)
    inside = _visible_normal_average(alpha, 1.0 / ior, cosines, refract=False, nodes=64)
    return Coat(ior, table, float(2.0 * np.mean(inside * cosines)))


def _coat_groups(s: SurfaceBatch):
    """(coat, row mask) for each (alpha, ior) present: one pass per coat, as a scene has few of them."""
    todo = np.ones(len(s.alpha), bool)
    while todo.any():
        first = int(np.argmax(todo))
        rows = todo & (s.alpha == s.alpha[first]) & (s.ior == s.ior[first])
        todo &= ~rows
        yield coat(float(s.alpha[first]), float(s.ior[first])), rows


def _coat_response(s: SurfaceBatch, *cosines: np.ndarray):
    """Per row: the coat's transmittance at each of `cosines`, and its internal reflectance."""
    transmittances = [np.empty(len(s.alpha)) for _ in cosines]
    internal = np.empty(len(s.alpha))
    for c, rows in _coat_groups(s):
        for t, cos in zip(transmittances, cosines, strict=True):
            t[rows] = c.transmittance(cos[rows])
        internal[rows] = c.internal_reflectance
    return transmittances, internal


def _spec_probability(s: SurfaceBatch, t_o: np.ndarray) -> np.ndarray:
    diffuse_weight = t_o * s.base.mean(axis=1)
    return np.clip((1.0 - t_o) / np.maximum(1.0 - t_o + diffuse_weight, 1e-12), 0.05, 1.0)


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
        cos_o, cos_i = np.clip(wo[:, 2], 0.0, 1.0), np.clip(wi[:, 2], 0.0, 1.0)
        (t_o, t_i), internal = _coat_response(s, cos_o, cos_i)
        spec_f, spec_pdf = _coat_eval(s, wo, wi)
        base_f = s.base * (t_o * t_i * cos_i * INV_PI / ((1.0 - internal) * s.ior**2))[:, None]
        p_spec = _spec_probability(s, t_o)
        pdf = p_spec * spec_pdf + (1.0 - p_spec) * cos_i * INV_PI
        return (spec_f[:, None] + base_f) * valid[:, None], np.where(valid, pdf, 0.0)

    def sample(self, s: SurfaceBatch, wo, u, uc):
        a = np.maximum(s.alpha, ALPHA_MIN)
        smooth = s.alpha <= 0
        (t_o,), _ = _coat_response(s, np.clip(wo[:, 2], 0.0, 1.0))
        p_spec = _spec_probability(s, t_o)
        choose_spec = uc < p_spec
        m = np.where(smooth[:, None], np.array([0.0, 0.0, 1.0]), sample_visible_normal(wo, a, u))
        wi = np.where(choose_spec[:, None], reflect(wo, m), square_to_cosine_hemisphere(u))
        valid = (wo[:, 2] > 0) & (wi[:, 2] > 0)
        delta = smooth & choose_spec
        # Smooth coat, specular chosen: the delta lobe alone, F / p_spec (F = 1 - T for a smooth coat).
        delta_weight = ((1.0 - t_o) / p_spec)[:, None] * np.ones((1, 3))
        # Otherwise the one-sample MIS mixture of both lobes.
        f_cos, pdf = self.eval(s, wo, wi)
        mixture_weight = f_cos / np.maximum(pdf, 1e-300)[:, None]
        weight = np.where(delta[:, None], delta_weight, mixture_weight) * valid[:, None]
        return wi, weight, np.where(valid & ~delta, pdf, 0.0), delta
