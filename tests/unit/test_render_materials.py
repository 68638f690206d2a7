"""BSDF families are plugins: one registered from here renders through the tracer, beside built-in ones."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from workers.render.bsdf import BSDF, MaterialParameters, SurfaceBatch, bsdf_code, register_material
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.render.sampling import INV_PI, square_to_cosine_hemisphere
from workers.scene.format import spec
from workers.scene.generators.builtin import cornell_box
from workers.scene.geometry.compile import CompiledScene, compile_scene


@dataclasses.dataclass(frozen=True)
class ToyLambertSpec:
    """A scene material of the toy family, as a kind would declare one."""

    albedo: tuple[float, float, float]
    type: str = "test_lambert"


@register_material("test_lambert")
class ToyLambert(BSDF):
    """Lambertian reflection with the albedo of the material: f = albedo / pi, cosine-weighted sampling."""

    def parameters(self, material: ToyLambertSpec) -> MaterialParameters:
        return MaterialParameters(base=material.albedo, roughness=1.0)

    def eval(self, s: SurfaceBatch, wo, wi):
        cos_i = np.where((wo[:, 2] > 0) & (wi[:, 2] > 0), wi[:, 2], 0.0)
        return s.base * (cos_i * INV_PI)[:, None], cos_i * INV_PI

    def sample(self, s: SurfaceBatch, wo, u, uc):
        wi = square_to_cosine_hemisphere(u)
        valid = wo[:, 2] > 0
        pdf, reflection = np.where(valid, wi[:, 2] * INV_PI, 0.0), np.ones(len(wo))
        return wi, s.base * valid[:, None], pdf, np.zeros(len(wo), bool), reflection


def with_material(scene: CompiledScene, name: str, material) -> CompiledScene:
    materials = {**scene.spec.materials, name: material}
    return dataclasses.replace(scene, spec=scene.spec.model_copy(update={"materials": materials}))


def test_a_registered_family_shades_like_the_builtin_one_it_mirrors_in_a_mixed_scene():
    """The Cornell box's white walls as the toy family: the other walls, boxes and the light keep the
    built-in `diffuse`, so every bounce dispatches a mixed batch; the image must be the built-in one."""
    compiled = compile_scene(cornell_box())
    white = compiled.spec.materials["white"]
    toy = with_material(compiled, "white", ToyLambertSpec(tuple(white.reflectance)))
    assert toy.materials[compiled.material_names.index("white")].type == "test_lambert"
    settings = RenderSettings(spp=4, width=24, height=24, aovs=True)
    ours, builtin = render(PathTracer(toy), settings), render(PathTracer(compiled), settings)
    assert builtin.image.mean() > 0.05
    np.testing.assert_allclose(ours.image, builtin.image, rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(ours.aovs["albedo"], builtin.aovs["albedo"])


def test_a_registered_family_in_a_white_furnace_returns_its_albedo():
    """A convex Lambertian ball under a constant environment L sends a L towards every viewer."""
    albedo, radiance = 0.6, 2.0
    scene = spec.SceneSpec(
        materials={"m": spec.Diffuse()},
        objects=[
            spec.SceneObject(name="ball", shape=spec.SphereShape(radius=1.0, subdivisions=4), material="m")
        ],
        environment=spec.ConstantBackground(radiance=(radiance,) * 3),
        camera=spec.Camera(position=(0, 0, 4), target=(0, 0, 0), width=32, height=32),
    )
    tracer = PathTracer(with_material(compile_scene(scene), "m", ToyLambertSpec((albedo,) * 3)))
    n = 20_000
    origins = np.tile([0.0, 0.0, 4.0], (n, 1))
    directions = np.tile([0.0, 0.0, -1.0], (n, 1))
    values = tracer.trace(origins, directions, np.random.default_rng(0), max_depth=2).radiance[:, 0]
    assert values.mean() == pytest.approx(albedo * radiance, rel=4 * values.std() / np.sqrt(n) + 1e-3)


def test_unknown_families_are_refused_with_the_registered_names():
    with pytest.raises(KeyError, match="test_lambert"):
        bsdf_code("no_such_family")
