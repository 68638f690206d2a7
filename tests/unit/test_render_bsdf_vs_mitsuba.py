"""Each BSDF family evaluated against the Mitsuba 3 plugin the comparisons export it as, direction by
direction: f |cos wi| and the pdf, at random pairs of directions (Mitsuba's si.wi is our wo)."""

import numpy as np
import pytest

import workers.render.bsdfs  # noqa: F401  (registers the built-in families)
from tests.support.mitsuba_scene import mitsuba_bsdf
from workers.render.bsdf import SurfaceBatch, bsdf_code, eval_bsdf
from workers.scene.format import spec

mi = pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba

N = 300
COLOUR = (0.5, 0.3, 0.2)

# (material, the rows it shades, f tolerance, pdf tolerance) relative to the largest value. Plastic's
# tolerances cover the quadratures of its coat (Mitsuba fits the smooth coat's internal reflectance to
# 0.1% and integrates the rough coat's on a finer grid); its pdf is Mitsuba's where our coat-sampling
# probability is not clamped, which COLOUR keeps it.
CASES = [
    (spec.Diffuse(reflectance=COLOUR), ("diffuse", COLOUR, 0.0, 1.5), 1e-6, 1e-6),
    (spec.Conductor(roughness=0.3, specular=COLOUR), ("conductor", COLOUR, 0.3, 1.5), 1e-6, 1e-6),
    (spec.Plastic(roughness=0.0, diffuse=COLOUR), ("plastic", COLOUR, 0.0, 1.5), 2e-3, 1e-6),
    (spec.Plastic(roughness=0.1, diffuse=COLOUR), ("plastic", COLOUR, 0.1, 1.5), 1e-3, 3e-3),
    (spec.Plastic(roughness=0.4, diffuse=COLOUR, ior=1.8), ("plastic", COLOUR, 0.4, 1.8), 1e-3, 3e-3),
    (spec.Dielectric(roughness=0.3, ior=1.5), ("dielectric", (1, 1, 1), 0.3, 1.5), 1e-6, 1e-6),
]


def mitsuba_eval(material: spec.Material, wo: np.ndarray, wi: np.ndarray):
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict(mitsuba_bsdf(material))
    ctx = mi.BSDFContext()
    f_cos, pdf = [], []
    for o, i in zip(wo, wi, strict=True):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(o)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        f_cos.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(i))))
        pdf.append(bsdf.pdf(ctx, si, mi.Vector3f(i)))
    return np.array(f_cos), np.array(pdf)


def random_directions(rng, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


@pytest.mark.parametrize(
    ("material", "rows", "f_tol", "pdf_tol"), CASES, ids=lambda c: getattr(c, "type", None)
)
def test_bsdf_evaluates_like_mitsuba(material, rows, f_tol, pdf_tol):
    rng = np.random.default_rng(0)
    wo, wi = random_directions(rng, N), random_directions(rng, N)
    if material.type == "dielectric":  # transmission, and light arriving from inside
        wi[::2, 2] *= -1
        wo[1::4, 2] *= -1
    kind, base, alpha, ior = rows
    s = SurfaceBatch(
        np.full(N, bsdf_code(kind), np.int8), np.tile(base, (N, 1)), np.full(N, alpha), np.full(N, ior)
    )
    f_cos, pdf = eval_bsdf(s, wo, wi)
    theirs_f, theirs_pdf = mitsuba_eval(material, wo, wi)
    assert np.abs(f_cos - theirs_f).max() <= f_tol * theirs_f.max()
    assert np.abs(pdf - theirs_pdf).max() <= pdf_tol * theirs_pdf.max()
