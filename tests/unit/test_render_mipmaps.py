"""Mipmapped texture lookups at camera-ray footprints (ray cones): the chain's levels, trilinear lookups,
and a far-away texture rendering as its average instead of aliasing."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.textures import MipChain, bilinear


def test_levels_halve_down_to_one_texel_and_keep_the_mean():
    image = np.random.default_rng(0).random((64, 32, 3)).astype(np.float32)
    chain = MipChain(image)
    assert [level.shape[:2] for level in chain.levels] == [(64 >> k, max(32 >> k, 1)) for k in range(7)]
    for level in chain.levels:
        np.testing.assert_allclose(level.mean((0, 1)), image.mean((0, 1)), rtol=1e-5)
    odd = MipChain(np.ones((5, 3, 3), np.float32))
    assert odd.levels[-1].shape == (1, 1, 3) and np.allclose(odd.levels[-1], 1.0)


def test_lookup_blends_the_two_levels_around_the_footprint():
    image = np.random.default_rng(1).random((16, 16, 3)).astype(np.float32)
    chain = MipChain(image)
    uv = np.random.default_rng(2).random((50, 2))
    np.testing.assert_allclose(chain.lookup(uv, "repeat", "repeat", None), bilinear(image, uv))
    np.testing.assert_allclose(
        chain.lookup(uv, "repeat", "repeat", np.full(50, -np.inf)), bilinear(image, uv)
    )
    np.testing.assert_allclose(
        chain.lookup(uv, "repeat", "repeat", np.full(50, 3.0)),
        np.tile(image.mean((0, 1)), (50, 1)),
        rtol=1e-5,
    )
    one_texel = np.full(50, -4.0)  # footprint 1/16 of UV: one texel wide, level 0
    np.testing.assert_allclose(chain.lookup(uv, "repeat", "repeat", one_texel), bilinear(image, uv))
    between = chain.lookup(uv, "repeat", "repeat", np.full(50, -3.5))
    expected = 0.5 * (bilinear(chain.levels[0], uv) + bilinear(chain.levels[1], uv))
    np.testing.assert_allclose(between, expected, rtol=1e-5)


def test_a_far_texture_renders_as_its_average_instead_of_aliasing(tmp_path):
    noise = (np.random.default_rng(3).random((512, 512)) > 0.5).astype(np.uint8) * 255
    Image.fromarray(np.repeat(noise[:, :, None], 3, axis=2)).save(tmp_path / "noise.png")
    camera = spec.Camera(position=(0, 3, 6), target=(0, 0, -4), width=24, height=24, fov=30)
    scene = spec.SceneSpec(
        materials={
            "ground": spec.Diffuse(reflectance=spec.ImageTexture(path="noise.png", color_space="linear"))
        },
        objects=[
            spec.SceneObject(
                name="ground",
                shape=spec.RectangleShape(),
                material="ground",
                transform=spec.Transform(rotate=(-90, 0, 0), scale=10),
            )
        ],
        lights=[spec.DirectionalLight(direction=(0, -1, 0), irradiance=(np.pi,) * 3)],
        camera=camera,
    )
    tracer = PathTracer(compile_scene(scene, tmp_path))
    pinhole = PinholeCamera(camera)
    ys, xs = np.mgrid[0:24, 0:24].reshape(2, -1) + 0.5
    images = {}
    for spread in (0.0, pinhole.spread):
        passes = []
        for seed in range(8):
            jitter = np.random.default_rng(seed).random((len(xs), 2)) - 0.5
            o, d = pinhole.rays(xs + jitter[:, 0], ys + jitter[:, 1])
            passes.append(
                tracer.trace(o, d, np.random.default_rng(seed), max_depth=2, spread=spread).radiance[:, 0]
            )
        images[spread] = np.array(passes)  # (passes, pixels): radiance = the texel's reflectance here
    o, d = pinhole.rays(xs, ys)
    on_ground = tracer.first_hits(o, d).hit
    assert on_ground.mean() > 0.5
    aliased, filtered = images[0.0][:, on_ground], images[pinhole.spread][:, on_ground]
    assert aliased.var(0).mean() > 20 * filtered.var(0).mean()  # point samples flicker 0/1; the mip is grey
    np.testing.assert_allclose(filtered.mean(), 0.5, atol=0.02)  # the texture's mean
    assert aliased.mean() == pytest.approx(filtered.mean(), abs=0.03)
