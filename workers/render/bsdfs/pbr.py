"""The metallic-roughness material of glTF 2.0 and UsdPreviewSurface: Mitsuba 3's `principled` BSDF
(Burley 2012, 2015) restricted to base colour, metallic, roughness, IOR and specular transmission (no
sheen, clearcoat, anisotropy, spec tint or flatness), which is how Mitsuba and Blender render glTF, with
a choice of diffuse lobe (`PbrMaterial.diffuse`): Burley's, as principled's, or an energy-conserving one.

With v the direction to the viewer (Mitsuba's si.wi), l the one to the light, h their half vector
(generalised for refraction), alpha = max(0.001, roughness^2), F_d the exact dielectric Fresnel term of
the IOR at v.h, and the lobe weights brdf = (1 - metallic)(1 - transmission) and
bsdf = (1 - metallic) transmission:

    reflection    [(1 - metallic) F_d + metallic Schlick(base, v.h)] D G / (4 |cos_v|)  (inside: bsdf F_d)
    transmission  sqrt(base) bsdf (1 - F_d) D G |v.h l.h| / (|cos_v| (v.h + eta l.h)^2)  (radiance: the
                  1/eta^2 of entering a denser medium cancels the eta^2 of the half-vector Jacobian)
    diffuse       brdf base / pi x, front only, with x by `diffuse`:
      burley               (1 - Fv/2)(1 - Fl/2) + retro-reflection Rr (Fl + Fv + Fl Fv (Rr - 1)),
                           Rr = 2 roughness (h.l)^2, F. = (1 - |cos .|)^5
      energy_conserving    (1 - E_s(cos_v)) (1 - E_s(cos_l)) / (1 - E_avg)

The energy-conserving lobe is albedo scaling (Kulla & Conty 2017, "Revisiting physically based shading at
Imageworks"; OpenPBR layers its dielectric base the same way): E_s(mu) is the directional albedo of the
dielectric reflection lobe above (F_d, single scattering), E_avg = 2 int E_s(mu) mu dmu, both tabulated
(`workers.render.bsdfs.dielectric_albedo`: per (alpha, IOR) for constant roughness, over roughness at the
IOR for textured roughness). The diffuse lobe then reflects (1 - E_s(cos_v)) base, so a white, non-metallic,
opaque surface reflects E_s + 1 - E_s = 1 at every angle and roughness; the lobe is reciprocal. The default,
and what the glTF and USD importers give: a white surface should not create light. Burley's is kept for
parity with Mitsuba's and Blender's principled (the Mitsuba comparisons use it); the metallic and
transmission lobes are the same code in both modes. Measured albedo of a white non-metal, IOR 1.5
(sampled, 200k directions, standard error <= 0.002; `tests/unit/test_render_pbr.py`):

    roughness   mode                 0 deg    45 deg   70 deg   85 deg   89 deg
    0.0         energy_conserving    0.998    0.999    0.998    1.000    1.000
                burley               1.014    1.024    1.085    1.279    1.431
    0.3         energy_conserving    0.999    0.999    0.998    0.999    1.000
                burley               1.033    1.043    1.126    1.210    1.190
    1.0         energy_conserving    0.998    0.998    0.999    1.000    1.000
                burley               1.046    1.049    1.147    1.439    1.568

(Mitsuba's principled: 1.43 at roughness 1 and 85 degrees.) The tables' error, against a 160-node
quadrature, is below 1e-3 in E_s except within a degree of grazing at roughness below ~0.1 (0.4% at
alpha 0.001, 1.7% on the textured table at roughness 0.05, both at cos 0.003).

Sampling picks a lobe with probabilities proportional to (1 - bsdf (1 - F_d(m)), bsdf (1 - F_d(m)), w_d)
for (reflection, transmission, diffuse) at a visible normal m (Heitz 2018), (F_d, 1 - F_d, 0) from inside,
with w_d the diffuse lobe's albedo over base: brdf for Burley's, brdf (1 - E_s(cos_v)) for the
energy-conserving one (it depends on v only, so `eval` computes the same pdf).

Rows with no transmission lobe (bsdf = 0) are two-sided (Mitsuba's `twosided` wrapper: the back side is
mirrored onto the front); transmissive rows see the back side as the inside of the object.
`SurfaceBatch.extra` holds (metallic, transmission, roughness, diffuse mode) per row.
"""

from __future__ import annotations

import numpy as np

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, register_material
from workers.render.bsdfs.dielectric_albedo import specular_albedo, specular_albedo_over_roughness
from workers.render.microfacet import (
    fresnel_dielectric,
    ggx_d,
    reflect,
    sample_visible_normal,
    smith_g1,
    visible_normal_pdf,
)
from workers.render.sampling import INV_PI, dot, normalize, safe_sqrt, square_to_cosine_hemisphere
from workers.scene.format import spec

ALPHA_FLOOR = 0.001  # Mitsuba's calc_dist_params: roughness 0 is a very sharp lobe, never a delta
METALLIC, TRANSMISSION, ROUGHNESS, DIFFUSE = 0, 1, 2, 3
# the DIFFUSE column: Burley's lobe, or albedo scaling with E_s tabulated at the row's alpha (constant
# roughness) or over roughness (textured roughness)
BURLEY, ALBEDO_SCALED, ALBEDO_SCALED_TEXTURED = 0.0, 1.0, 2.0
DIFFUSE_MODES = {"burley": BURLEY, "energy_conserving": ALBEDO_SCALED}


def gltf_alpha(roughness: np.ndarray | float) -> np.ndarray:
    """GGX alpha of a glTF (perceptual) roughness."""
    return np.maximum(ALPHA_FLOOR, np.square(roughness))


def schlick_weight(cos: np.ndarray) -> np.ndarray:
    return np.clip(1.0 - cos, 0.0, 1.0) ** 5


def schlick(r0: np.ndarray, cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Schlick's Fresnel from normal-incidence reflectance `r0` (N, 3); the transmitted cosine where the
    light leaves the denser side (Mitsuba's calc_schlick)."""
    eta_it = np.where(cos_i >= 0, eta, 1.0 / eta)
    cos_t = safe_sqrt(1.0 - (1.0 - cos_i * cos_i) / (eta_it * eta_it))
    w = np.where(eta_it > 1.0, schlick_weight(np.abs(cos_i)), schlick_weight(cos_t))[:, None]
    return w + r0 * (1.0 - w)


def _weights(s: SurfaceBatch):
    metallic, transmission = s.extra[:, METALLIC], s.extra[:, TRANSMISSION]
    return (1.0 - metallic) * (1.0 - transmission), (1.0 - metallic) * transmission


def _specular_albedo(s: SurfaceBatch, *cosines: np.ndarray):
    """Per row: E_s of the dielectric reflection lobe at each of `cosines`, and E_avg (0 on Burley rows);
    one table per (alpha, ior) of constant roughness, one per ior for textured roughness."""
    albedos = [np.zeros(len(s.alpha)) for _ in cosines]
    average = np.zeros(len(s.alpha))
    mode = s.extra[:, DIFFUSE]
    todo = mode != BURLEY
    while todo.any():
        first = int(np.argmax(todo))
        rows = todo & (mode == mode[first]) & (s.ior == s.ior[first])
        if mode[first] == ALBEDO_SCALED:
            rows &= s.alpha == s.alpha[first]
            table, roughness = specular_albedo(float(s.alpha[first]), float(s.ior[first])), None
        else:
            table = specular_albedo_over_roughness(float(s.ior[first]), ALPHA_FLOOR)
            roughness = s.extra[rows, ROUGHNESS]
        todo &= ~rows
        for albedo, cos in zip(albedos, cosines, strict=True):
            albedo[rows], average[rows] = table.at(cos[rows], roughness)
    return albedos, average


def _diffuse_weight(s: SurfaceBatch, brdf: np.ndarray, albedo_v: np.ndarray) -> np.ndarray:
    """The diffuse lobe's selection weight: its albedo over base, brdf (1 - E_s(cos_v)) when albedo-scaled."""
    return brdf * np.where(s.extra[:, DIFFUSE] == BURLEY, 1.0, 1.0 - albedo_v)


def _mirror(s: SurfaceBatch, wo: np.ndarray) -> np.ndarray:
    """-1 on opaque rows seen from the back (mirrored onto the front), else 1."""
    _, bsdf = _weights(s)
    return np.where((bsdf <= 0) & (wo[:, 2] < 0), -1.0, 1.0)


def _flip_z(v: np.ndarray, sign: np.ndarray) -> np.ndarray:
    out = v.copy()
    out[:, 2] *= sign
    return out


@register_material("pbr")
class MetallicRoughness(BSDF):
    two_sided = False  # per row instead: see `_mirror`

    def parameters(self, material: spec.PbrMaterial) -> MaterialParameters:
        return MaterialParameters(
            base=material.base_color,
            alpha=float(gltf_alpha(material.roughness)),
            ior=material.ior,
            roughness=float(gltf_alpha(material.roughness)),  # the AOV reports GGX alpha, as for the others
            extra=(
                material.metallic,
                material.transmission,
                material.roughness,
                DIFFUSE_MODES[material.diffuse],
            ),
        )

    def textures(self, material: spec.PbrMaterial) -> dict:
        slots = {
            "base_color": material.base_color_texture,
            "metallic_roughness": material.metallic_roughness_texture,
            "transmission": material.transmission_texture,
            "normal": material.normal_texture,
            "emission": material.emission_texture,
        }
        return {slot: texture for slot, texture in slots.items() if texture is not None}

    def apply_textures(self, material: spec.PbrMaterial, s: SurfaceBatch, lookups) -> None:
        """glTF: texels multiply the factors; roughness in G and metallic in B of one linear texture."""
        if "base_color" in lookups:
            s.base = s.base * lookups["base_color"]
        if "metallic_roughness" in lookups:
            texel = lookups["metallic_roughness"]
            s.extra[:, ROUGHNESS] = material.roughness * texel[:, 1]
            s.extra[:, METALLIC] = material.metallic * texel[:, 2]
            s.alpha = gltf_alpha(s.extra[:, ROUGHNESS])
            s.extra[s.extra[:, DIFFUSE] == ALBEDO_SCALED, DIFFUSE] = ALBEDO_SCALED_TEXTURED
        if "transmission" in lookups:
            s.extra[:, TRANSMISSION] = material.transmission * lookups["transmission"][:, 0]

    def eval(self, s: SurfaceBatch, wo, wi):
        side = _mirror(s, wo)
        return self._eval(s, _flip_z(wo, side), _flip_z(wi, side))

    def _eval(self, s: SurfaceBatch, v, l):
        """f |cos_l| (N, 3) and pdf (N,) for v, l as Mitsuba's principled sees them (module docstring)."""
        brdf, bsdf = _weights(s)
        roughness = s.extra[:, ROUGHNESS]
        metallic = s.extra[:, METALLIC]
        transmissive = s.extra[:, TRANSMISSION] > 0
        eta, a = s.ior, s.alpha
        cos_v, cos_l = v[:, 2], l[:, 2]
        active = cos_v != 0
        reflection, refraction = cos_v * cos_l > 0, cos_v * cos_l < 0
        front = cos_v > 0
        eta_path = np.where(front, eta, 1.0 / eta)
        h = normalize(v + l * np.where(reflection, 1.0, eta_path)[:, None])
        h *= np.where(h[:, 2] < 0, -1.0, 1.0)[:, None]
        v_h, l_h = dot(v, h), dot(l, h)
        f_d, _, _ = fresnel_dielectric(v_h, eta)
        outward = np.where(cos_v >= 0, 1.0, -1.0)
        v_m, l_m = v_h * outward, l_h * outward
        reflect_ok = reflection & (v_m > 0) & (l_m > 0)
        refract_ok = refraction & (v_m > 0) & (l_m < 0)
        d, g = ggx_d(h, a), smith_g1(v, h, a) * smith_g1(l, h, a)
        abs_cos_v = np.maximum(np.abs(cos_v), 1e-300)

        fresnel = (1.0 - metallic)[:, None] * f_d[:, None] + metallic[:, None] * schlick(s.base, v_h, eta)
        fresnel = np.where(front[:, None], fresnel, (bsdf * f_d)[:, None])
        specular = np.where(active & reflect_ok & (f_d > 0), d * g / (4.0 * abs_cos_v), 0.0)
        value = fresnel * specular[:, None]

        denom = np.maximum((v_h + eta_path * l_h) ** 2, 1e-300)
        transmitted = bsdf * np.abs((1.0 - f_d) * d * g * v_h * l_h / (abs_cos_v * denom))
        transmitted = np.where(active & transmissive & (bsdf > 0) & refract_ok & (f_d < 1), transmitted, 0.0)
        value += np.sqrt(s.base) * transmitted[:, None]

        fo, fi = schlick_weight(np.abs(cos_l)), schlick_weight(np.abs(cos_v))
        retro = 2.0 * roughness * l_h**2
        burley = (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo) + retro * (fo + fi + fo * fi * (retro - 1.0))
        (albedo_v, albedo_l), average = _specular_albedo(s, cos_v, cos_l)
        scaled = (1.0 - albedo_v) * (1.0 - albedo_l) / (1.0 - average)
        lobe = np.where(s.extra[:, DIFFUSE] == BURLEY, burley, scaled)
        diffuse = np.where(
            active & (brdf > 0) & reflection & front, brdf * np.abs(cos_l) * INV_PI * lobe, 0.0
        )
        value += s.base * diffuse[:, None]

        p_reflect = np.where(front, 1.0 - bsdf * (1.0 - f_d), f_d)
        p_transmit = np.where(transmissive, np.where(front, bsdf * (1.0 - f_d), 1.0 - f_d), 0.0)
        p_diffuse = np.where(front, _diffuse_weight(s, brdf, albedo_v), 0.0)
        total = np.maximum(p_reflect + p_transmit + p_diffuse, 1e-300)
        jacobian = np.abs(
            np.where(reflection, 1.0 / np.where(l_h == 0, 1e-300, 4.0 * l_h), eta_path**2 * l_h / denom)
        )
        visible = visible_normal_pdf(v * outward[:, None], h, a) * jacobian
        pdf = np.where(reflect_ok, p_reflect * visible, 0.0)
        pdf += np.where(reflection & front, p_diffuse * cos_l * INV_PI, 0.0)
        pdf += np.where(transmissive & refract_ok, p_transmit * visible, 0.0)
        pdf = np.where(active, pdf / total, 0.0)
        return np.where(active[:, None], value, 0.0), pdf

    def sample(self, s: SurfaceBatch, wo, u, uc):
        side = _mirror(s, wo)
        v = _flip_z(wo, side)
        brdf, bsdf = _weights(s)
        transmissive = s.extra[:, TRANSMISSION] > 0
        cos_v = v[:, 2]
        front = cos_v > 0
        outward = np.where(cos_v >= 0, 1.0, -1.0)
        m = sample_visible_normal(v * outward[:, None], s.alpha, u)
        v_m = dot(v, m)
        f_d, cos_t, eta_ti = fresnel_dielectric(v_m, s.ior)
        p_transmit = np.where(transmissive, np.where(front, bsdf * (1.0 - f_d), 1.0 - f_d), 0.0)
        (albedo_v,), _ = _specular_albedo(s, cos_v)
        p_diffuse = np.where(front, _diffuse_weight(s, brdf, albedo_v), 0.0)
        total = np.where(front, 1.0 - bsdf * (1.0 - f_d), f_d) + p_transmit + p_diffuse
        p_diffuse, p_transmit = p_diffuse / total, p_transmit / total
        choose_diffuse = uc < p_diffuse
        choose_transmit = ~choose_diffuse & (uc < p_diffuse + p_transmit)
        refracted = (v_m * eta_ti + cos_t)[:, None] * m - eta_ti[:, None] * v
        l = np.where(choose_transmit[:, None], normalize(refracted), reflect(v, m))
        l = np.where(choose_diffuse[:, None], square_to_cosine_hemisphere(u), l)
        sides_ok = np.where(choose_transmit, cos_v * l[:, 2] < 0, cos_v * l[:, 2] > 0)
        m_out = m * outward[:, None]
        microfacet_ok = (dot(v, m_out) > 0) & np.where(choose_transmit, dot(l, m_out) < 0, dot(l, m_out) > 0)
        valid = (cos_v != 0) & (front | (bsdf > 0)) & sides_ok & (choose_diffuse | microfacet_ok)
        f_cos, pdf = self._eval(s, v, l)
        valid &= pdf > 0
        weight = np.where(valid[:, None], f_cos / np.maximum(pdf, 1e-300)[:, None], 0.0)
        eta = np.where(valid & choose_transmit, 1.0 / eta_ti, 1.0)  # the sampled event's relative IOR
        return _flip_z(l, side), weight, np.where(valid, pdf, 0.0), np.zeros(len(v), bool), eta
