"""Our path tracer against Mitsuba 3 `scalar_rgb` on the same triangles, materials and lights.

Both renderers are unbiased estimators of the same image, so their difference must be explained
by noise. Each renders K independent seeds; pixels are averaged into blocks; per block and
channel the standard error of each renderer's mean comes from the spread over seeds, and
z = (ours - mitsuba) / sqrt(se_ours^2 + se_mitsuba^2) is then approximately standard normal.

Bounds, and why:
- Bias: per seed, the whole image's mean per channel is close to normal (a sum over many pixels);
  the difference of the two renderers' means over seeds, divided by its standard error, is
  t-distributed (~14 dof) under agreement; we require |t| < 4 (p ~ 1e-3 per channel). Studentised
  per-block z are not used for bias: path-tracing noise is skewed, so a low block mean comes with
  a low variance estimate, and their mean drifts negative even for identical estimators.
- Outliers: under agreement |z| > 4 has probability 6e-5 per block; heavy-tailed caustic noise
  and a 7-dof standard-error estimate fatten the tails, so we allow 2% of the blocks.
- Mean relative error: with Gaussian noise E|ours - mitsuba| = sqrt(2/pi) sigma, so the MRE
  that noise alone explains is mean(sqrt(2/pi) sigma / mitsuba); we require the observed MRE to
  be at most 1.3x that (the sample mean over >= 192 blocks is within ~5% of its expectation).
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.mitsuba_scene import render_mitsuba
from workers.render.render import RenderSettings, render
from workers.scene import spec
from workers.scene.builtin import cornell_box, cornell_glossy, ground
from workers.scene.compile import compile_scene

pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba

SEEDS = 8
SIZE = 64
BLOCK = 8


def block_means(image: np.ndarray) -> np.ndarray:
    n = SIZE // BLOCK
    return image.reshape(n, BLOCK, n, BLOCK, 3).mean(axis=(1, 3))


def compare(scene: spec.SceneSpec, spp: int, max_depth: int, tmp_path):
    compiled = compile_scene(scene)
    ours = np.stack(
        [
            block_means(
                render(
                    compiled, RenderSettings(spp=spp, width=SIZE, height=SIZE, max_depth=max_depth, seed=s)
                ).image.astype(np.float64)
            )
            for s in range(SEEDS)
        ]
    )
    theirs = np.stack(
        [
            block_means(
                render_mitsuba(compiled, tmp_path / "mi", spp, max_depth, seed=s, width=SIZE, height=SIZE)
            )
            for s in range(SEEDS)
        ]
    )
    mean_o, mean_m = ours.mean(0), theirs.mean(0)
    se = np.sqrt(ours.var(0, ddof=1) / SEEDS + theirs.var(0, ddof=1) / SEEDS)
    lit = mean_m > 1e-3 * mean_m.max()
    z = (mean_o - mean_m)[lit] / np.maximum(se[lit], 1e-12)
    totals_o, totals_m = ours.mean(axis=(1, 2)), theirs.mean(axis=(1, 2))  # (SEEDS, 3)
    total_se = np.sqrt(totals_o.var(0, ddof=1) / SEEDS + totals_m.var(0, ddof=1) / SEEDS)
    global_t = (totals_o.mean(0) - totals_m.mean(0)) / np.maximum(total_se, 1e-12)
    mre = np.mean(np.abs(mean_o - mean_m)[lit] / mean_m[lit])
    noise_mre = np.mean(np.sqrt(2 / np.pi) * se[lit] / mean_m[lit])
    summary = (
        f"image-mean t {np.round(global_t, 2)}, |z|>4 in {np.mean(np.abs(z) > 4):.1%} of {z.size} blocks, "
        f"MRE {mre:.4f} vs noise-explained {noise_mre:.4f}, means {mean_o.mean():.5f} / {mean_m.mean():.5f}"
    )
    print(summary)
    assert np.all(np.abs(global_t) < 4), summary
    assert np.mean(np.abs(z) > 4) <= 0.02, summary
    assert mre <= 1.3 * noise_mre, summary


def test_cornell_box_agrees_with_mitsuba(tmp_path):
    compare(cornell_box(), spp=32, max_depth=8, tmp_path=tmp_path)


def test_cornell_glossy_agrees_with_mitsuba(tmp_path):
    """Rough metal reflections and a glass sphere with caustics."""
    compare(cornell_glossy(), spp=32, max_depth=8, tmp_path=tmp_path)


def env_lit_comparison_scene() -> spec.SceneSpec:
    """Diffuse, rough-metal and rough-glass spheres on a ground plane under a rotated real HDRI."""

    def ball(name, material, x):
        return spec.SceneObject(
            name=name,
            shape=spec.SphereShape(center=(x, 0.5, 0), radius=0.5, subdivisions=4),
            material=material,
        )

    return spec.SceneSpec(
        name="env_lit_comparison",
        materials={
            "ground": spec.Diffuse(reflectance=(0.5, 0.5, 0.5)),
            "clay": spec.Diffuse(reflectance=(0.7, 0.4, 0.2)),
            "metal": spec.Conductor(roughness=0.2, specular=(0.9, 0.9, 0.9)),
            "frosted": spec.Dielectric(ior=1.5, roughness=0.3),
        },
        objects=[
            ground(6.0),
            ball("clay", "clay", -1.2),
            ball("metal", "metal", 0.0),
            ball("frosted", "frosted", 1.2),
        ],
        environment=spec.EnvironmentMap(builtin="courtyard", rotate=(0, 60, 0)),
        camera=spec.Camera(position=(0, 1.6, 4.5), target=(0, 0.4, 0), fov=35),
    )


def test_environment_lit_scene_agrees_with_mitsuba(tmp_path):
    compare(env_lit_comparison_scene(), spp=16, max_depth=6, tmp_path=tmp_path)
