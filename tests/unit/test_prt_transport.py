"""`prt` ground truth: binned transport rows against rendering under the same cube map, and the hard
cases of the direct/indirect split (issue 15)."""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.prt.gbuffer import surface_inputs
from workers.models.prt.lighting import CubeMapLight, relit_tracer, uniform_cube
from workers.models.prt.transport import BACKGROUND, DIRECT, INDIRECT, trace_rows
from workers.models.prt.views import pixel_rays
from workers.render.stratified import StratifiedUniforms
from workers.scene.format import spec
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SIZE = 4
MAX_DEPTH = 6
ALL = (BACKGROUND, DIRECT, INDIRECT)


@pytest.fixture(scope="module")
def glossy_row():
    scene = compile_scene(get_builtin("glossy_row"))
    camera = scene.spec.camera.model_copy(update={"width": 10, "height": 10, "fov": 75.0})
    return scene, pixel_rays(camera)


def lighting(seed: int, sun: float = 0.0) -> np.ndarray:
    cube = np.random.default_rng(seed).uniform(0.0, 2.0, (6, SIZE, SIZE, 3))
    if sun:
        cube[2, 1, 2] = sun  # one texel above the scene, as bright as a sun
    return cube


def same_stream(seed: int, pixels: int, spp: int = 1) -> StratifiedUniforms:
    """The random stream `trace_rows` traces `pixels` x `spp` paths with (one chunk)."""
    return StratifiedUniforms(np.random.default_rng(seed), pixels, spp)


def tracers_with_the_same_paths(scene, cube):
    """A tracer under a white cube (what rows are traced with) and one rendering `cube` with its sampler."""
    rows_tracer = relit_tracer(scene, uniform_cube(SIZE))
    render_tracer = relit_tracer(scene, uniform_cube(SIZE))
    render_tracer.lights.environment = CubeMapLight(cube, rows_tracer.lights.environment.sampler)
    return rows_tracer, render_tracer


@pytest.mark.parametrize("sun", [0.0, 1e5])
def test_bin_then_dot_equals_rendering_under_the_map_with_the_same_random_numbers(glossy_row, sun):
    scene, (origins, directions) = glossy_row
    cube = lighting(1, sun)
    rows_tracer, render_tracer = tracers_with_the_same_paths(scene, cube)
    rows = trace_rows(rows_tracer, origins, directions, 1, SIZE, np.random.default_rng(7), MAX_DEPTH, ALL)
    rendered = render_tracer.trace(origins, directions, same_stream(7, len(origins)), MAX_DEPTH).radiance
    binned = rows.radiance(cube)
    assert np.isfinite(binned).all() and binned.max() > 0
    np.testing.assert_allclose(binned, rendered, rtol=1e-9, atol=1e-12 * max(sun, 1.0))
    if sun:
        assert binned.max() > 10.0  # the sun's light does reach the pixels through the rows


def test_bin_then_dot_agrees_with_an_independent_render_within_the_standard_error(glossy_row):
    scene, (origins, directions) = glossy_row
    cube = lighting(2)
    rows_tracer, render_tracer = tracers_with_the_same_paths(scene, cube)
    spp = 32
    rows = trace_rows(rows_tracer, origins, directions, spp, SIZE, np.random.default_rng(1), MAX_DEPTH, ALL)
    binned = rows.radiance(cube).mean()
    paths = render_tracer.trace(
        np.repeat(origins, spp, 0), np.repeat(directions, spp, 0), np.random.default_rng(2), MAX_DEPTH
    ).radiance.mean(1)
    standard_error = paths.std() / np.sqrt(len(paths))
    assert abs(binned - paths.mean()) < 4 * np.sqrt(2) * standard_error


def test_stratified_rows_are_unbiased_and_less_noisy_than_independent_ones(glossy_row):
    """A pixel's paths take strata of their first bounce: over independent seeds, the indirect light of the
    rows keeps its mean (within the standard error) and loses variance."""
    scene, (origins, directions) = glossy_row
    cube = lighting(6)
    rows_tracer = relit_tracer(scene, uniform_cube(SIZE))

    def indirect(stratified: bool, seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)
        rows = trace_rows(rows_tracer, origins, directions, 16, SIZE, rng, MAX_DEPTH, stratified=stratified)
        return rows.radiance(cube, ("indirect",))

    runs = {s: np.stack([indirect(s, seed) for seed in range(12)]) for s in (False, True)}
    lit = runs[False].mean(0).sum(1) > 0.05  # pixels with indirect light
    assert lit.sum() > 20
    means = {s: r[:, lit].mean() for s, r in runs.items()}
    standard_errors = {s: r[:, lit].mean((1, 2)).std() / np.sqrt(len(r)) for s, r in runs.items()}
    assert abs(means[True] - means[False]) < 4 * np.hypot(*standard_errors.values())
    variance = {s: r[:, lit].var(0).mean() for s, r in runs.items()}
    assert variance[True] < 0.9 * variance[False]  # 0.77 measured (seeds 0-11)


def test_direct_rows_match_a_two_segment_render_and_pixels_seeing_the_sky_are_background(glossy_row):
    scene, (origins, directions) = glossy_row
    cube = lighting(3)
    rows_tracer, render_tracer = tracers_with_the_same_paths(scene, cube)
    rows = trace_rows(rows_tracer, origins, directions, 1, SIZE, np.random.default_rng(4), 2, ALL)
    direct = render_tracer.trace(origins, directions, same_stream(4, len(origins)), 2).radiance
    np.testing.assert_allclose(rows.radiance(cube, ("background", "direct")), direct, rtol=1e-9, atol=1e-12)
    assert not rows.indirect.any()  # two segments hold no indirect light
    sky = ~surface_inputs(rows_tracer, origins, directions).hit
    assert sky.any() and not rows.direct[sky].any() and rows.background[sky].any()
    assert not rows.background[~sky].any()


def test_a_convex_object_alone_has_no_indirect_light():
    box = spec.SceneSpec(
        materials={"m": spec.Conductor(roughness=0.3)},
        objects=[spec.SceneObject(name="box", shape=spec.BoxShape(), material="m")],
        environment=spec.ConstantBackground(),
        camera=spec.Camera(position=(2.0, 1.5, 3.0), width=10, height=10),
    )
    scene = compile_scene(box)
    origins, directions = pixel_rays(scene.spec.camera)
    tracer = relit_tracer(scene, uniform_cube(SIZE))
    rows = trace_rows(tracer, origins, directions, 8, SIZE, np.random.default_rng(0), MAX_DEPTH, ALL)
    assert rows.direct.any()
    assert not rows.indirect.any()


@pytest.mark.parametrize("roughness", [0.0, 1e-3, 1.0])
def test_mirror_to_rough_surfaces_give_finite_rows_and_their_lobes(roughness):
    mirror_on_floor = spec.SceneSpec(
        materials={"metal": spec.Conductor(roughness=roughness), "floor": spec.Diffuse()},
        objects=[
            spec.SceneObject(name="ball", shape=spec.SphereShape(subdivisions=2), material="metal"),
            spec.SceneObject(
                name="floor", shape=spec.RectangleShape(), material="floor",
                transform=spec.Transform(translate=(0.0, -1.0, 0.0), rotate=(-90.0, 0.0, 0.0), scale=4.0),
            ),
        ],
        environment=spec.ConstantBackground(),
        camera=spec.Camera(position=(0.0, 0.5, 4.0), width=8, height=8),
    )  # fmt: skip
    scene = compile_scene(mirror_on_floor)
    origins, directions = pixel_rays(scene.spec.camera)
    cube = lighting(5, sun=1e5)
    rows_tracer, render_tracer = tracers_with_the_same_paths(scene, cube)
    rows = trace_rows(rows_tracer, origins, directions, 1, SIZE, np.random.default_rng(9), MAX_DEPTH, ALL)
    rendered = render_tracer.trace(origins, directions, same_stream(9, len(origins)), MAX_DEPTH).radiance
    np.testing.assert_allclose(rows.radiance(cube), rendered, rtol=1e-9, atol=1e-7)
    inputs = surface_inputs(rows_tracer, origins, directions)
    ball = inputs.object_id == 0
    assert ball.any() and (inputs.kd[ball] == 0).all() and (inputs.ks[ball] > 0.9).all()
    floor = inputs.object_id == 1
    assert (inputs.roughness[floor] == 1).all() and (inputs.ks[floor] == 0).all()
    assert np.allclose(np.linalg.norm(inputs.reflected[inputs.hit], axis=1), 1.0)
