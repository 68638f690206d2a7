"""Russian roulette by Mitsuba's rule: paths inside glass survive as often as the same paths outside it.

A transmission scales a path's throughput by 1/eta^2 (radiance compression), so roulette on the throughput
alone kills paths inside glass ~2.25x more often and weights the survivors up by as much: more variance
through every glass object, at no gain. The wavefront carries each path's product of squared relative IORs
and roulette survives with q = min(max(beta) * eta^2, 0.95), as Mitsuba's path integrator does."""

from __future__ import annotations

import numpy as np

from tests.unit.test_render_analytic import ball, scene_with, sphere_pixels
from workers.render import wavefront
from workers.render.bsdf import SurfaceBatch, bsdf_code, sample_bsdf
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene

IOR = 1.5
N = 10_000


def glass(n: int) -> SurfaceBatch:
    return SurfaceBatch(
        family=np.full(n, bsdf_code("dielectric"), np.int8),
        base=np.ones((n, 3)),
        alpha=np.zeros(n),
        ior=np.full(n, IOR),
    )


def through_interface(beta, eta2, wo_z: float, u_roulette):
    """A smooth dielectric's transmission at normal incidence (wo_z > 0: entering, < 0: leaving), then the
    wavefront's step to the next paths with roulette on: (sampled eta, next_paths' outputs)."""
    n = len(u_roulette)
    wo = np.tile([0.0, 0.0, wo_z], (n, 1))
    sampled = sample_bsdf(glass(n), wo, np.full((n, 2), 0.5), np.full(n, 0.999))  # uc > F: transmit
    frame = np.tile(np.eye(3), (n, 1, 1))
    out = wavefront.next_paths(
        np.arange(n), np.tile(beta, (n, 1)), np.full(n, eta2), sampled,
        (frame[:, 0].copy(), frame[:, 1].copy(), frame[:, 2].copy()),
        np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1)), np.ones(n), u_roulette, True,
    )  # fmt: skip
    return sampled[4], out


def test_a_path_inside_glass_survives_roulette_by_mitsuba_s_rule():
    """Entering glass: the sample reports eta = 1.5, the path's eta^2 becomes 2.25, and with throughput 0.6 it
    survives with q = min(0.6 / 2.25 * 2.25, 0.95) = 0.6 (not 0.27), weighted 1 / q. Leaving: eta = 1/1.5
    and the product is back to 1."""
    u = (np.arange(N) + 0.5) / N
    beta = np.array([0.6, 0.3, 0.1])
    eta, (idx, _, d, out_beta, eta2, _, _) = through_interface(beta, 1.0, 1.0, u)
    np.testing.assert_allclose(eta, IOR)
    assert d[:, 2].max() < 0  # refracted into the glass
    q = min(beta.max() / IOR**2 * IOR**2, 0.95)
    assert len(idx) == round(q * N)
    np.testing.assert_allclose(out_beta, np.tile(beta / IOR**2 / q, (len(idx), 1)), rtol=1e-12)
    np.testing.assert_allclose(eta2, IOR**2, rtol=1e-15)

    eta, (_, _, _, out_beta, eta2, _, _) = through_interface(beta / IOR**2, IOR**2, -1.0, u)
    np.testing.assert_allclose(eta, 1 / IOR)
    np.testing.assert_allclose(eta2, 1.0, rtol=1e-15)
    np.testing.assert_allclose(out_beta[0], beta / 0.6, rtol=1e-12)


def test_roulette_through_a_glass_ball_stays_unbiased_with_little_variance():
    """A smooth glass ball under a uniform sky returns the sky's radiance L exactly on every path without
    roulette. With roulette from the first bounce, Mitsuba's rule survives ~0.95 per bounce (per-sample
    relative variance ~0.1-0.2); roulette on the throughput alone keeps 0.44 of the paths that enter the
    glass and weights them x2.25 (relative variance ~1.4). The mean stays L either way."""
    radiance = 2.0
    scene = scene_with([ball()], {"m": spec.Dielectric(ior=IOR, roughness=0.0)}, spec.ConstantBackground(
        radiance=(radiance,) * 3
    ))  # fmt: skip
    tracer = PathTracer(compile_scene(scene))
    spp = 16
    image = render(tracer, RenderSettings(spp=spp, max_depth=64, rr_depth=1)).image.astype(np.float64)
    px = sphere_pixels(image, tracer)[:, 0]
    assert np.isfinite(image).all()
    relative_variance = px.var() * spp / radiance**2  # of one sample's estimate
    assert relative_variance < 0.4
    assert abs(px.mean() - radiance) < 4 * px.std() / np.sqrt(len(px)) + 1e-3
