"""Emission textures and spot lights in the path tracer, against quadratures of what they should give."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from workers.render.integrator import PathTracer
from workers.render.lights import spot_falloff
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene
from workers.scene.importers.textures import evaluate_texture, load_image_texture

FLOOR_ALBEDO = 0.5


def floor() -> spec.SceneObject:
    return spec.SceneObject(
        name="floor",
        shape=spec.RectangleShape(),
        material="floor",
        transform=spec.Transform(rotate=(-90, 0, 0), scale=20),
    )


def radiance_at(tracer: PathTracer, point, n: int = 100_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error of the direct (max_depth 2) radiance leaving the floor at `point` upwards."""
    origins = np.tile(np.add(point, (0.0, 0.3, 0.0)), (n, 1))
    directions = np.tile([0.0, -1.0, 0.0], (n, 1))
    result = tracer.trace(origins, directions, np.random.default_rng(seed), max_depth=2)
    return result.radiance.mean(0), result.radiance.std(0) / np.sqrt(n)


def test_an_emission_texture_lights_the_floor_as_its_texels_say(tmp_path):
    """A downward panel at height 1 whose emission is a texture: the floor's radiance below it equals
    albedo / pi times the integral of the texture's radiance cos cos / r^2 over the panel (both light
    sampling and BSDF-sampled hits on the panel see the texture, or their MIS sum would be off)."""
    pixels = np.random.default_rng(1).integers(0, 256, (4, 4, 3)).astype(np.uint8)
    Image.fromarray(pixels).save(tmp_path / "glow.png")
    texture = spec.ImageTexture(path="glow.png")
    scene = spec.SceneSpec(
        materials={
            "floor": spec.Diffuse(reflectance=(FLOOR_ALBEDO,) * 3),
            "panel": spec.PbrMaterial(base_color=(0, 0, 0), metallic=0.0, emission_texture=texture),
        },
        objects=[
            floor(),
            spec.SceneObject(
                name="panel",
                shape=spec.RectangleShape(),
                material="panel",
                emission=(3.0, 3.0, 3.0),
                transform=spec.Transform(rotate=(90, 0, 0), translate=(0, 1, 0), scale=0.5),
            ),
        ],
    )
    tracer = PathTracer(compile_scene(scene, tmp_path))
    image = load_image_texture(texture, "t", tmp_path)
    s, t = np.meshgrid(*(np.linspace(-1, 1, 401)[:-1] + 1 / 400,) * 2, indexing="ij")
    s, t = s.ravel(), t.ravel()
    uv = np.stack([(s + 1) / 2, (t + 1) / 2], axis=1)  # the rectangle's UVs: (-1, -1) is (0, 0)
    emitted = 3.0 * evaluate_texture(texture, image, uv).astype(np.float64)
    for point in [(0.0, 0.0, 0.0), (0.3, 0.0, -0.2), (1.0, 0.0, 0.5)]:
        offset = np.stack([0.5 * s - point[0], np.ones_like(s), 0.5 * t - point[2]], axis=1)
        r2 = (offset**2).sum(1)
        geometry = 1.0 / r2**2 * 0.25 * (2 / 400) ** 2  # cos cos / r^2 dA with both cosines 1 / r
        expected = FLOOR_ALBEDO / np.pi * (emitted * geometry[:, None]).sum(0)
        mean, err = radiance_at(tracer, point)
        np.testing.assert_allclose(mean, expected, atol=4 * err.max() + 1e-3 * expected.max())
    # the texture changes the answer (a constant 1 would give another one)
    assert np.ptp(expected) > 10 * err.max()


@pytest.mark.parametrize("angle", [0.0, 15.0, 25.0, 40.0])
def test_a_spot_light_falls_off_as_gltf_says(angle):
    spot = spec.SpotLight(
        position=(0, 1, 0), direction=(0, -1, 0), intensity=(2, 2, 2), inner_cone=10, outer_cone=30
    )
    scene = spec.SceneSpec(
        materials={"floor": spec.Diffuse(reflectance=(FLOOR_ALBEDO,) * 3)}, objects=[floor()], lights=[spot]
    )
    tracer = PathTracer(compile_scene(scene))
    x = np.tan(np.radians(angle))
    mean, _ = radiance_at(tracer, (x, 0.0, 0.0), n=64)
    cos = np.cos(np.radians(angle))
    t = np.clip((cos - np.cos(np.radians(30))) / (np.cos(np.radians(10)) - np.cos(np.radians(30))), 0, 1)
    expected = FLOOR_ALBEDO / np.pi * 2.0 * t * t * cos / (1 + x * x)
    np.testing.assert_allclose(mean, expected, rtol=1e-6, atol=1e-12)
    assert spot_falloff(np.array([cos]), np.cos(np.radians([[10.0, 30.0]])))[0] == pytest.approx(t * t)
