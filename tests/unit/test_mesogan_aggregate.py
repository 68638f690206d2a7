"""The shell as the path tracer's aggregate: the scatter/uncollided mixture is unbiased for a known
constant extinction, shadow rays pass with the transmittance, the base is opaque, and events keep their
shell coordinates; in the path tracer, the shell is lit as its rho says by every light type, receives other
objects' shadows and casts its own by its transmittance."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

from workers.models.mesogan.aggregate import NeuralMaterial, ShellAggregate, pack_events, unpack_events
from workers.models.mesogan.config import PRESETS, MesoganConfig
from workers.models.mesogan.covering import build_shell, covering
from workers.models.mesogan.networks import MesoGAN
from workers.models.mesogan.sampling import (
    Instance,
    View,
    cone_radius,
    hemisphere,
    slab_scene,
    stack_views,
    to_scene,
)
from workers.models.mesogan.shell import Shell
from workers.models.mesogan.slab import Window, draw_noise, generate_planes, render_slab
from workers.models.mesogan.volume import mip_stack
from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.scene.format.spec import (
    Appearance,
    BoxShape,
    Camera,
    ConstantBackground,
    Diffuse,
    DirectionalLight,
    EnvironmentMap,
    PointLight,
    RectangleShape,
    SceneObject,
    SceneSpec,
    SpotLight,
    Structure,
    Transform,
)
from workers.scene.generators.builtin import ground
from workers.scene.geometry.compile import compile_scene

SIGMA = 0.8  # extinction per shell height


class ConstantMaterial(NeuralMaterial):
    """A test double of the decoder: constant extinction, constant rho (the estimator's known inputs)."""

    widest_footprint = math.inf

    def __init__(self) -> None:
        pass

    def hidden(self, uv, height, variance, radius):
        return torch.full((len(uv),), SIGMA, dtype=torch.float64), torch.zeros(len(uv), 1)

    def rho(self, hidden, light, view):
        return np.full((len(hidden), 3), 0.25)


def square_shell(height: float = 1.0) -> Shell:
    v = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    normals = np.tile([0.0, 0.0, 1.0], (2, 3, 1))
    return Shell(v[faces], normals, (v[faces][..., :2] + 5) / 10, height)


def test_scattering_is_chosen_with_probability_one_minus_transmittance():
    aggregate = ShellAggregate(square_shell(), ConstantMaterial(), samples=8)
    n = 4000
    rng = np.random.default_rng(0)
    origins = np.tile([-6.0, 0.0, 0.5], (n, 1))  # through both side faces, 10 units inside, above the base
    directions = np.tile([1.0, 0.0, 0.0], (n, 1))
    events = aggregate.first_events(origins, directions, np.zeros(n), np.full(n, np.inf), rng)
    p = 1 - math.exp(-SIGMA * 10.0)
    short = aggregate.first_events(origins, directions, np.zeros(n), np.full(n, 1.5), rng)  # 0.5 inside
    q = 1 - math.exp(-SIGMA * 0.5)
    for found, expected in ((events.found, p), (short.found, q)):
        z = (found.mean() - expected) / math.sqrt(expected * (1 - expected) / n)
        assert abs(z) < 4, (found.mean(), expected)
    assert np.all(events.weight == 1)
    t = short.t[short.found]
    assert (t >= 1.0).all() and (t <= 1.5).all()


def test_the_base_is_opaque_and_shadow_rays_pass_with_the_transmittance():
    aggregate = ShellAggregate(square_shell(), ConstantMaterial(), samples=8)
    n = 2000
    rng = np.random.default_rng(1)
    down = aggregate.first_events(
        np.column_stack([rng.uniform(-4, 4, (n, 2)), np.full(n, 3.0)]),
        np.tile([0.0, 0.0, -1.0], (n, 1)),
        np.zeros(n),
        np.full(n, np.inf),
        rng,
    )
    assert down.found.all()
    origins = np.column_stack([np.full(n, -6.0), rng.uniform(-4, 4, n), rng.uniform(0.1, 0.9, n)])
    blocked = aggregate.occluded(origins, np.tile([1.0, 0.0, 0.0], (n, 1)), np.zeros(n), np.full(n, 8.0))
    expected = 1 - math.exp(-SIGMA * 7.0)
    assert abs(blocked.mean() - expected) < 4 * math.sqrt(expected * (1 - expected) / n)


def test_events_keep_their_shell_coordinates_and_continuing_rays_leave_the_shell():
    rng = np.random.default_rng(2)
    prism = rng.integers(0, 1 << 30, 100)
    b = rng.dirichlet([1, 1, 1], 100)
    height, variance, radius = rng.uniform(0, 1, (3, 100))
    p2, b2, h2, v2, r2 = unpack_events(pack_events(prism, b, height, variance, radius))
    assert np.array_equal(p2, prism) and np.abs(b2 - b).max() < 1e-7 and np.abs(h2 - height).max() < 2**-20
    assert np.allclose(v2, variance, rtol=1e-7) and np.allclose(r2, radius, rtol=1e-7)
    aggregate = ShellAggregate(square_shell(0.5), ConstantMaterial(), samples=4)
    origins = np.array([[0.0, 0.0, 0.1], [4.0, 4.0, 0.3]])
    directions = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    exits = aggregate.exit_distance(np.zeros((2, 3), np.int64), origins, directions)
    assert np.allclose(exits, [0.4, min(0.2 / 0.8, 1.0 / 0.6)])


class ConstantTransfer(ConstantMaterial):
    """Constant extinction and a constant rho for light from above the slab (zero from below)."""

    def rho(self, hidden, light, view):
        return np.where(light[:, 2:] > 0, RHO, 0.0) * np.ones((1, 3))


RHO, SUN, SKY = 0.1, 2.0, 0.5


def test_a_path_traced_shell_over_an_opaque_base_has_the_analytic_radiance():
    """Every camera ray reaching the covered floor scatters in the shell (its base is opaque: the floor's own
    red material is never seen through it), so a pixel's radiance is rho (E + 2 pi A): the sun's irradiance
    E and the sky A over the upper hemisphere. The shell is thin (0.02) and seen from 4 units away, where
    Embree's float32 hit distance lands the floor up to 1e-5 shell heights off the prism's base."""
    spec = SceneSpec(
        name="slab",
        materials={"fur": Diffuse(reflectance=(1.0, 0.0, 0.0))},
        objects=[ground(40.0, "fur")],
        lights=[DirectionalLight(direction=(0.3, -1.0, 0.2), irradiance=(SUN,) * 3)],
        environment=ConstantBackground(radiance=(SKY,) * 3),
        camera=Camera(position=(0.0, 3.0, 3.0), target=(0.0, 0.0, 0.0), fov=40.0, width=16, height=16),
    )
    scene = compile_scene(spec)
    shell = build_shell(scene, covering(scene, ["fur"], 0.02, 0.25), 0.02)
    tracer = PathTracer(scene, aggregate=ShellAggregate(shell, ConstantTransfer(), samples=4))
    image = render(tracer, RenderSettings(spp=4, max_depth=3, seed=0, threads=1)).image
    expected = RHO * (SUN + 2 * math.pi * SKY)
    assert np.allclose(image.mean((0, 1)), expected, rtol=0.08), (image.mean((0, 1)), expected)


def flat_slab(distance: float, size: int, floor: float):
    """An untrained quick model made dense (so the strands' rho carries the light, not only the skin's),
    one plane over a `floor`-wide square, labels, a camera `distance` slab heights away with `size`^2
    pixels, and the shell over the floor with the plane laid on it, as `render_slab` sees it."""
    config = MesoganConfig.model_validate(PRESETS["quick"])
    torch.manual_seed(0)
    model = MesoGAN(config).eval()
    with torch.no_grad():
        [m for m in model.decoder.trunk.modules() if isinstance(m, torch.nn.Linear)][-1].bias[0] += 3.0
    eye = distance * hemisphere(math.radians(70), 0.4)
    camera = Camera(
        position=tuple(to_scene(eye)), target=(0.0, 0.0, 0.0), fov=config.fov, width=size, height=size
    )
    instance = Instance(Structure(), Appearance(hue=0.3), hemisphere(math.radians(40), 2.0), camera, 0)
    batch = stack_views([View(instance, np.zeros((size, size, 3)), np.zeros(size * size))], size)
    side = round(floor / config.texel)
    window = Window((-side // 2, -side // 2), (side, side), config.texel)
    with torch.no_grad():
        planes = generate_planes(
            model, config, batch["structure"], torch.randn(1, config.latent_dims),
            draw_noise(model, config, 1, 0), window,
        )  # fmt: skip
    spec = slab_scene(config, instance).model_copy(update={"objects": [ground(floor, "skin")]})
    scene = compile_scene(spec)
    # The floor's v runs along the slab's -y: flipped, the plane's (x, y) lie along the slab's (x, y).
    scene = dataclasses.replace(scene, uvs=scene.uvs * np.float32([1, -1]) + np.float32([0, 1]))
    shell = build_shell(scene, covering(scene, ["skin"], 1.0, config.texel), 1.0)
    material = NeuralMaterial(
        model, config, mip_stack(planes, config.mip_levels), window, batch["appearance"][0]
    )
    return config, model, planes, window, batch, scene, shell, material


def slab_mean(config, model, planes, window, batch, renders: int) -> np.ndarray:
    """`render_slab`'s mean colour over `renders` jittered renders: what the discriminator trained on."""
    with torch.no_grad():
        images = [
            render_slab(model, config, planes, window, batch, jitter=True).image[0] for _ in range(renders)
        ]
    return torch.stack(images).mean((0, 2, 3)).numpy()


def shell_mean(config, scene, shell, material, size: int, spp: int) -> np.ndarray:
    cone = cone_radius(config.fov, size)
    tracer = PathTracer(scene, aggregate=ShellAggregate(shell, material, config.samples_per_ray, cone))
    settings = RenderSettings(spp=spp, width=size, height=size, max_depth=config.max_depth, seed=0, threads=1)
    return render(tracer, settings).image.mean((0, 1))


def test_the_shell_path_traced_over_a_flat_slab_matches_the_training_renderer():
    """The transport the tracer runs through the shell (the scattered term with the sun and one traced
    path for the sky, light and view in the tangent frame, the opaque skin) against `render_slab`, what the
    discriminator trained on: one plane, one set of labels, a flat slab seen from well inside its edges."""
    config, model, planes, window, batch, scene, shell, material = flat_slab(2.5, 16, 7.0)
    trained_view = slab_mean(config, model, planes, window, batch, 16)
    traced = shell_mean(config, scene, shell, material, 16, 32)
    assert np.allclose(traced, trained_view, rtol=0.05), (traced, trained_view)


def test_a_far_view_of_the_shell_matches_the_training_renderer_at_trained_footprints():
    """A view 8 times farther than the training cameras, at 8^2 pixels: each pixel's cone is some 30 times
    wider than any the decoder was trained at (a furred mesh seen from across a room). The shell must not
    query the decoder at footprints training never rendered (its integrated height encoding and mip level
    would be out of distribution: on the default preset's fur ball the shell rendered 1.5 times too bright);
    averaged over its pixels' jittered rays, it must equal the training renderer's view at 128^2, whose
    footprints are within the trained range (but narrower than the shell's clamped ones: 1-3% apart).
    Without the clamp, 7-10% apart in green and blue."""
    config, model, planes, window, batch, scene, shell, material = flat_slab(20.0, 128, 24.0)
    trained_view = slab_mean(config, model, planes, window, batch, 4)
    traced = shell_mean(config, scene, shell, material, 8, 64)
    assert np.allclose(traced, trained_view, rtol=0.05), (traced, trained_view)


def covered_floor(lights, environment=None, objects=(), size: int = 16, height: float = 0.02):
    """The floor covered by a thin constant shell, seen from above, under `lights`: the tracer, the floor
    points the pixel-centre rays meet (N, 3) and the compiled scene."""
    spec = SceneSpec(
        name="slab",
        materials={"fur": Diffuse(reflectance=(1.0, 0.0, 0.0)), "grey": Diffuse(reflectance=(0.5,) * 3)},
        objects=[ground(40.0, "fur"), *objects],
        lights=lights,
        environment=environment,
        camera=Camera(position=(0.0, 3.0, 2.0), target=(0.0, 0.0, 0.0), fov=40.0, width=size, height=size),
    )
    scene = compile_scene(spec)
    shell = build_shell(scene, covering(scene, ["fur"], height, 0.25), height)
    tracer = PathTracer(scene, aggregate=ShellAggregate(shell, ConstantTransfer(), samples=4))
    py, px = np.mgrid[0:size, 0:size] + 0.5
    origins, directions = PinholeCamera(spec.camera, size, size).rays(px.ravel(), py.ravel())
    floor = origins - (origins[:, 1] / directions[:, 1])[:, None] * directions
    return tracer, floor, scene


def traced(tracer, spp: int = 8) -> np.ndarray:
    """The frame's red channel as (N,) pixels in image order (the constant rho is grey)."""
    return render(tracer, RenderSettings(spp=spp, max_depth=3, seed=0, threads=1)).image[..., 0].ravel()


def test_the_shell_is_lit_by_every_light_type_as_its_rho_says():
    """rho is radiance per unit irradiance from a direction, so a point or spot light adds rho I / d^2, an
    area light rho times its radiance integrated over the solid angle it subtends, an environment map rho
    times its radiance integrated over the upper hemisphere (rho is 0 from below)."""
    light = np.array([0.3, 2.0, 0.2])
    intensity = 5.0
    for lamp in (
        PointLight(position=tuple(light), intensity=(intensity,) * 3),
        SpotLight(
            position=tuple(light),
            direction=(0, -1, 0),
            intensity=(intensity,) * 3,
            inner_cone=70,
            outer_cone=80,
        ),
    ):
        tracer, floor, _ = covered_floor([lamp])
        expected = RHO * intensity / ((floor - light) ** 2).sum(1)
        assert np.allclose(traced(tracer).mean(), expected.mean(), rtol=0.05), lamp.type

    emitter = SceneObject(
        name="lamp", shape=RectangleShape(), material="grey", emission=(20.0,) * 3,
        transform=Transform(translate=(0.3, 2.0, 0.2), rotate=(90, 0, 0), scale=0.2),
    )  # fmt: skip
    tracer, floor, _ = covered_floor([], objects=[emitter])
    g = (np.arange(8) + 0.5) / 8 * 0.4 - 0.2  # the 0.4-wide emitter facing down, in 8 x 8 patches
    patches = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    points = np.column_stack([0.3 + patches[:, 0], np.full(len(patches), 2.0), 0.2 + patches[:, 1]])
    to_lamp = points[None] - floor[:, None]
    d2 = (to_lamp**2).sum(-1)
    solid_angle = (0.4**2 / len(patches)) * to_lamp[..., 1] / np.sqrt(d2) / d2
    expected = RHO * 20.0 * solid_angle.sum(1)
    assert np.allclose(traced(tracer, 16).mean(), expected.mean(), rtol=0.08), "area"

    sky = EnvironmentMap(procedural="sky", params={"sun_irradiance": 0.0})  # no disc: smooth to integrate
    tracer, _, scene = covered_floor([], environment=sky)
    image = scene.environment_image.astype(np.float64)[..., 0]  # lat-long, row i at theta (i + 1/2) pi / H
    rows, cols = image.shape
    theta = (np.arange(rows) + 0.5) / rows * np.pi
    above = theta < np.pi / 2
    upper = (image[above] * np.sin(theta[above])[:, None]).sum() * (np.pi / rows) * (2 * np.pi / cols)
    assert np.allclose(traced(tracer, 16).mean(), RHO * upper, rtol=0.08), "environment"


def test_shadows_fall_onto_the_shell_and_from_it():
    """A box between the sun and the covered floor casts its shadow on the shell (0 there: no sky); the
    shell over a raised square, thick and seen by the sun at 45 degrees, shades the floor beside the
    square's own shadow by its transmittance exp(-sigma * length in shell heights)."""
    beside = DirectionalLight(direction=(-1.0, -1.0, 0.0), irradiance=(SUN,) * 3)
    box = SceneObject(
        name="box", shape=BoxShape(), material="grey", transform=Transform(translate=(0.8, 1.0, 0), scale=0.3)
    )
    tracer, floor, _ = covered_floor([beside], objects=[box], size=24)
    # the box spans x 0.5-1.1 and y 0.7-1.3: the sun rays of floor points at x from -0.8 to 0.4 cross it
    x, z = floor[:, 0], floor[:, 2]
    in_shadow = (x > -0.6) & (x < 0.2) & (np.abs(z) < 0.2)
    lit = ((x < -0.9) | (np.abs(z) > 0.4)) & (x < 0.6)  # and the box itself unseen
    image = traced(tracer)
    assert in_shadow.sum() > 10 and image[in_shadow].max() < 0.05 * RHO * SUN
    assert np.allclose(image[lit].mean(), RHO * SUN, rtol=0.05)

    # The shell over a square raised to y = 1 (height 0.5, up to y = 1.5): floor points at z in (-2, -1.5)
    # see the sun through the shell's volume only, 2 + z of its height.
    raised = SceneObject(
        name="raised", shape=RectangleShape(), material="fur",
        transform=Transform(translate=(0, 1.0, 0), rotate=(-90, 0, 0), scale=0.5),
    )  # fmt: skip
    spec = SceneSpec(
        name="raised",
        materials={"fur": Diffuse(reflectance=(1.0, 0.0, 0.0)), "grey": Diffuse(reflectance=(0.5,) * 3)},
        objects=[ground(40.0, "grey"), raised],
        lights=[DirectionalLight(direction=(0.0, -1.0, -1.0), irradiance=(SUN,) * 3)],
        camera=Camera(position=(0.0, 3.0, -4.5), target=(0.0, 0.0, -1.75), fov=30.0, width=24, height=24),
    )
    scene = compile_scene(spec)
    shell = build_shell(scene, covering(scene, ["fur"], 0.5, 0.25), 0.5)
    tracer = PathTracer(scene, aggregate=ShellAggregate(shell, ConstantTransfer(), samples=4))
    py, px = np.mgrid[0:24, 0:24] + 0.5
    origins, directions = PinholeCamera(spec.camera).rays(px.ravel(), py.ravel())
    floor = origins - (origins[:, 1] / directions[:, 1])[:, None] * directions
    inside = np.clip(2.0 + floor[:, 2], 0.0, 0.5)  # the sun ray's rise inside the shell
    transmittance = np.exp(-SIGMA * np.sqrt(2) * inside / 0.5)
    lit_floor = 0.5 / math.pi * SUN / math.sqrt(2)
    image = render(tracer, RenderSettings(spp=32, max_depth=2, seed=0, threads=1)).image[..., 0].ravel()
    strip = (np.abs(floor[:, 0]) < 0.4) & (floor[:, 2] > -1.95) & (floor[:, 2] < -1.55)
    open_floor = (np.abs(floor[:, 0]) > 0.6) | (floor[:, 2] < -2.05)
    assert strip.sum() > 10 and transmittance[strip].mean() < 0.8
    assert np.allclose(image[open_floor].mean(), lit_floor, rtol=0.05)
    assert np.allclose(image[strip].mean(), lit_floor * transmittance[strip].mean(), rtol=0.08)
