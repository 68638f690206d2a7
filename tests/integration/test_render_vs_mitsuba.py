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
- Mean relative error: with Gaussian noise E|ours - mitsuba| = sqrt(2/pi) sigma, so the error
  that noise alone explains is sum(sqrt(2/pi) sigma) / sum(mitsuba) over the lit blocks; we require
  the observed sum|ours - mitsuba| / sum(mitsuba) to be at most 1.3x that (a sum over >= 150 blocks
  is within ~5% of its expectation). Relative to the image's brightness, not per block: an average
  of per-block relative errors is ruled by a handful of nearly black blocks whose relative noise is
  50% (seen on the glTF scene: 3 of 471 block channels moved it by 0.007), so it stops being close
  to its expectation. A bias anywhere still shows here in proportion to its light, and a local one
  in the per-block z above.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.support.mitsuba_scene import render_mitsuba
from workers.render.render import RenderSettings, render
from workers.scene.format import spec
from workers.scene.generators.builtin import cornell_box, cornell_glossy, ground
from workers.scene.geometry import shapes
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import load_scene

mi = pytest.importorskip("mitsuba")
pytestmark = pytest.mark.mitsuba

SEEDS = 8
SIZE = 64
BLOCK = 8


def block_means(image: np.ndarray) -> np.ndarray:
    n = SIZE // BLOCK
    return image.reshape(n, BLOCK, n, BLOCK, 3).mean(axis=(1, 3))


def render_ours(
    scene: spec.SceneSpec, spp: int, max_depth: int, base_dir=None
) -> Callable[[int], np.ndarray]:
    compiled = compile_scene(scene, base_dir)
    settings = dict(spp=spp, width=SIZE, height=SIZE, max_depth=max_depth)
    return lambda seed: render(compiled, RenderSettings(**settings, seed=seed)).image.astype(np.float64)


def render_exported(scene: spec.SceneSpec, spp: int, max_depth: int, workdir, base_dir=None):
    """Mitsuba rendering our compiled scene (tests/support/mitsuba_scene.py)."""
    compiled = compile_scene(scene, base_dir)
    return lambda seed: render_mitsuba(compiled, workdir, spp, max_depth, seed=seed, width=SIZE, height=SIZE)


def compare(scene: spec.SceneSpec, spp: int, max_depth: int, tmp_path, base_dir=None):
    compare_renders(
        render_ours(scene, spp, max_depth, base_dir),
        render_exported(scene, spp, max_depth, tmp_path / "mi", base_dir),
    )


def compare_renders(ours_at: Callable[[int], np.ndarray], theirs_at: Callable[[int], np.ndarray]):
    """Two renderers, each a seed -> (SIZE, SIZE, 3) image, agree up to noise (module docstring)."""
    ours = np.stack([block_means(ours_at(s)) for s in range(SEEDS)])
    theirs = np.stack([block_means(theirs_at(s)) for s in range(SEEDS)])
    mean_o, mean_m = ours.mean(0), theirs.mean(0)
    se = np.sqrt(ours.var(0, ddof=1) / SEEDS + theirs.var(0, ddof=1) / SEEDS)
    lit = mean_m > 1e-3 * mean_m.max()
    z = (mean_o - mean_m)[lit] / np.maximum(se[lit], 1e-12)
    totals_o, totals_m = ours.mean(axis=(1, 2)), theirs.mean(axis=(1, 2))  # (SEEDS, 3)
    total_se = np.sqrt(totals_o.var(0, ddof=1) / SEEDS + totals_m.var(0, ddof=1) / SEEDS)
    global_t = (totals_o.mean(0) - totals_m.mean(0)) / np.maximum(total_se, 1e-12)
    mre = np.sum(np.abs(mean_o - mean_m)[lit]) / np.sum(mean_m[lit])
    noise_mre = np.sum(np.sqrt(2 / np.pi) * se[lit]) / np.sum(mean_m[lit])
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


MITSUBA_CORNELL_NAMES = {
    "floor": "floor",
    "ceiling": "ceiling",
    "back": "back",
    "green_wall": "green-wall",
    "red_wall": "red-wall",
    "light": "light",
    "small_box": "small-box",
    "large_box": "large-box",
}


def test_cornell_box_is_mitsubas_cornell_box():
    """`cornell_box` claims to be `mitsuba.cornell_box()`: shapes, transforms, reflectances, light, camera."""
    mi.set_variant("scalar_rgb")
    theirs, ours = mi.cornell_box(), cornell_box()
    assert {o.name for o in ours.objects} == set(MITSUBA_CORNELL_NAMES)
    assert {k for k, v in theirs.items() if isinstance(v, dict) and "to_world" in v} - {"sensor"} == set(
        MITSUBA_CORNELL_NAMES.values()
    )
    unit_shapes = {"rectangle": shapes.rectangle(), "box": shapes.box()}
    for obj in ours.objects:
        entry = theirs[MITSUBA_CORNELL_NAMES[obj.name]]
        assert entry["type"] == {"rectangle": "rectangle", "box": "cube"}[obj.shape.type], obj.name
        np.testing.assert_allclose(obj.transform.to_matrix(), np.array(entry["to_world"].matrix), atol=1e-6)
        reflectance = theirs[entry["bsdf"]["id"]]["reflectance"]["value"]
        np.testing.assert_allclose(ours.materials[obj.material].reflectance, reflectance, err_msg=obj.name)
        emitted = entry["emitter"]["radiance"]["value"] if "emitter" in entry else None
        assert obj.emission == (tuple(emitted) if emitted else None), obj.name
        assert not obj.two_sided_emission
        # The unit shapes themselves: the same corners, and the same outward faces.
        mesh = unit_shapes[obj.shape.type]
        loaded = mi.traverse(mi.load_dict({"type": entry["type"]}))
        if "vertex_positions" in loaded:  # the cube is a mesh; Mitsuba's rectangle is analytic
            corners = np.array(loaded["vertex_positions"]).reshape(-1, 3)
            assert set(map(tuple, np.unique(corners, axis=0))) == set(
                map(tuple, np.unique(mesh.vertices, axis=0))
            )
        else:
            np.testing.assert_allclose(mesh.vertices[:, :2], [[-1, -1], [1, -1], [1, 1], [-1, 1]])
            np.testing.assert_allclose(mesh.normals, np.tile([0, 0, 1], (4, 1)))
    sensor, camera = theirs["sensor"], ours.camera
    look_at = mi.ScalarTransform4f().look_at(origin=camera.position, target=camera.target, up=camera.up)
    np.testing.assert_allclose(np.array(look_at.matrix), np.array(sensor["to_world"].matrix), atol=1e-6)
    assert camera.fov == sensor["fov"]
    assert (camera.width, camera.height) == (sensor["film"]["width"], sensor["film"]["height"])
    assert camera.width == camera.height  # so fov_axis "smaller" is our vertical fov


def test_cornell_box_agrees_with_mitsuba_loading_its_own_cornell_box():
    """Mitsuba renders the scene it builds itself (analytic rectangles, its cube), not our export."""
    mi.set_variant("scalar_rgb")
    spp, max_depth = 32, 8

    def theirs(seed: int) -> np.ndarray:
        scene = mi.cornell_box()
        scene["integrator"]["max_depth"] = max_depth
        scene["sensor"]["film"] |= {"width": SIZE, "height": SIZE, "rfilter": {"type": "box"}}
        scene["sensor"]["sampler"]["sample_count"] = spp
        return np.array(mi.render(mi.load_dict(scene), spp=spp, seed=seed), dtype=np.float64)[..., :3]

    compare_renders(render_ours(cornell_box(), spp, max_depth), theirs)


def test_cornell_glossy_agrees_with_mitsuba(tmp_path):
    """Rough metal reflections and a glass sphere with caustics."""
    compare(cornell_glossy(), spp=32, max_depth=8, tmp_path=tmp_path)


def ball(name: str, material: str, x: float, radius: float = 0.5) -> spec.SceneObject:
    return spec.SceneObject(
        name=name,
        shape=spec.SphereShape(center=(x, radius, 0), radius=radius, subdivisions=4),
        material=material,
    )


def env_lit_comparison_scene() -> spec.SceneSpec:
    """Diffuse, rough-metal, rough-glass, rough- and smooth-plastic spheres on a ground plane under a
    rotated real HDRI."""
    return spec.SceneSpec(
        name="env_lit_comparison",
        materials={
            "ground": spec.Diffuse(reflectance=(0.5, 0.5, 0.5)),
            "clay": spec.Diffuse(reflectance=(0.7, 0.4, 0.2)),
            "metal": spec.Conductor(roughness=0.2, specular=(0.9, 0.9, 0.9)),
            "frosted": spec.Dielectric(ior=1.5, roughness=0.3),
            "rough_plastic": spec.Plastic(diffuse=(0.2, 0.5, 0.7), roughness=0.3),
            "glossy_plastic": spec.Plastic(diffuse=(0.8, 0.2, 0.2), roughness=0.0, ior=1.6),
        },
        objects=[
            ground(8.0),
            ball("clay", "clay", -2.2, 0.45),
            ball("metal", "metal", -1.1, 0.45),
            ball("frosted", "frosted", 0.0, 0.45),
            ball("rough_plastic", "rough_plastic", 1.1, 0.45),
            ball("glossy_plastic", "glossy_plastic", 2.2, 0.45),
        ],
        environment=spec.EnvironmentMap(builtin="courtyard", rotate=(0, 60, 0)),
        camera=spec.Camera(position=(0, 2.0, 5.5), target=(0, 0.3, 0), fov=45),
    )


def test_environment_lit_scene_agrees_with_mitsuba(tmp_path):
    compare(env_lit_comparison_scene(), spp=16, max_depth=6, tmp_path=tmp_path)


def plastic_comparison_scene() -> spec.SceneSpec:
    """Four plastic spheres filling the frame (smooth to rough, two indices) under a rotated HDRI."""
    spheres = [
        (-0.55, 0.55, 0.0, 1.5),
        (0.55, 0.55, 0.1, 1.5),
        (-0.55, -0.55, 0.3, 1.5),
        (0.55, -0.55, 0.6, 1.8),
    ]
    return spec.SceneSpec(
        name="plastic_comparison",
        materials={
            f"plastic_{i}": spec.Plastic(diffuse=(0.7, 0.4, 0.2), roughness=roughness, ior=ior)
            for i, (_, _, roughness, ior) in enumerate(spheres)
        },
        objects=[
            spec.SceneObject(
                name=f"sphere_{i}",
                shape=spec.SphereShape(center=(x, y, 0), radius=0.5, subdivisions=5),
                material=f"plastic_{i}",
            )
            for i, (x, y, _, _) in enumerate(spheres)
        ],
        environment=spec.EnvironmentMap(builtin="courtyard", rotate=(0, 60, 0)),
        camera=spec.Camera(position=(0, 0, 4.0), target=(0, 0, 0), fov=32),
    )


def test_plastic_agrees_with_mitsuba(tmp_path):
    compare(plastic_comparison_scene(), spp=16, max_depth=4, tmp_path=tmp_path)


def lights_and_textures_scene() -> spec.SceneSpec:
    """A point light, a directional light and a procedural sky; checker-textured diffuse ground and
    plastic, an image-textured (PNG, sRGB) wall, a slightly rough plastic (alpha 0.05)."""
    checker = spec.CheckerTexture(color0=(0.8, 0.75, 0.7), color1=(0.15, 0.2, 0.3), scale=6)
    return spec.SceneSpec(
        name="lights_and_textures",
        materials={
            "ground": spec.Diffuse(reflectance=checker),
            "wall": spec.Diffuse(reflectance=spec.ImageTexture(path="wall.png")),
            "checker_plastic": spec.Plastic(diffuse=checker.model_copy(update={"scale": 4}), roughness=0.0),
            "satin_plastic": spec.Plastic(diffuse=(0.6, 0.6, 0.2), roughness=0.05),
        },
        objects=[
            spec.SceneObject(
                name="ground",
                shape=spec.ProceduralShape(generator="ground_plane", params={"size": 6.0, "uv_tiles": 2.0}),
                material="ground",
            ),
            spec.SceneObject(
                name="wall",
                shape=spec.RectangleShape(),
                material="wall",
                transform=spec.Transform(translate=(0, 1.0, -1.5), scale=(2.0, 1.0, 1.0)),
            ),
            ball("checker_plastic", "checker_plastic", -0.7),
            ball("satin_plastic", "satin_plastic", 0.7),
        ],
        lights=[
            spec.PointLight(position=(1.5, 2.5, 1.5), intensity=(6.0, 5.0, 4.0)),
            spec.DirectionalLight(direction=(-0.5, -1.0, -0.3), irradiance=(1.0, 1.1, 1.3)),
        ],
        environment=spec.EnvironmentMap(
            procedural="sky", params={"sun_irradiance": 0.0, "sun_azimuth": 120.0}, scale=0.5
        ),
        camera=spec.Camera(position=(0, 1.8, 4.5), target=(0, 0.6, 0), fov=40),
    )


def write_wall_texture(folder) -> None:
    """A coarse 8 x 4 texture of distinct colours: a flipped or shifted lookup changes the image."""
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(20, 235, size=(4, 8, 3), dtype=np.uint8)).save(folder / "wall.png")


def test_lights_textures_and_procedural_sky_agree_with_mitsuba(tmp_path):
    write_wall_texture(tmp_path)
    compare(lights_and_textures_scene(), spp=16, max_depth=6, tmp_path=tmp_path, base_dir=tmp_path)


SHARED_SCENE = Path(__file__).resolve().parents[2] / "assets" / "scenes" / "mitsuba" / "shared_scene"


def test_a_scene_file_each_renderer_loads_itself_agrees():
    """shared_scene.yaml through our loader, shared_scene.xml through Mitsuba's: transforms, point and
    directional lights, a checker texture, plastic and metal, a rotated and scaled HDRI file."""
    mi.set_variant("scalar_rgb")
    spp, max_depth = 16, 6
    scene, base_dir = load_scene(SHARED_SCENE.with_suffix(".yaml"))

    def theirs(seed: int) -> np.ndarray:
        loaded = mi.load_file(
            str(SHARED_SCENE.with_suffix(".xml")), spp=spp, max_depth=max_depth, resolution=SIZE
        )
        return np.array(mi.render(loaded, spp=spp, seed=seed), dtype=np.float64)[..., :3]

    compare_renders(render_ours(scene, spp, max_depth, base_dir), theirs)
