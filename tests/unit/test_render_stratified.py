"""Stratified samples per pixel (`workers.render.stratified`): every stratum once, the same expected image
as independent samples, less noise."""

from __future__ import annotations

import numpy as np
import pytest

from tests.unit.test_render_analytic import floor, reflected_by_a_floor, scene_with
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.render.stratified import grid, stratified
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene


@pytest.mark.parametrize(("spp", "dims"), [(16, 2), (8, 2), (7, 2), (16, 1), (1, 2)])
def test_each_pixel_takes_every_stratum_once(spp, dims):
    groups = ((0, 1),) if dims == 2 else ((0,),)
    u = stratified(np.random.default_rng(0), 5, spp, groups).reshape(5, spp, dims)
    assert ((u >= 0) & (u < 1)).all()
    sizes = grid(spp) if dims == 2 else (spp,)
    cells = np.floor(u * np.asarray(sizes)).astype(int)
    flat = cells[..., 0] + (cells[..., 1] * sizes[0] if dims == 2 else 0)
    assert all(sorted(pixel) == list(range(spp)) for pixel in flat)


def test_a_subset_of_paths_keeps_the_strata_all_paths_would_take():
    """The first vertex's uniforms of the paths that hit lie in those paths' strata among every path's."""
    groups, paths = ((0,), (1, 2)), np.array([0, 3, 5, 6, 11])
    every = np.floor(stratified(np.random.default_rng(1), 3, 4, groups) * [4, 2, 2])
    subset = np.floor(stratified(np.random.default_rng(1), 3, 4, groups, paths) * [4, 2, 2])
    assert np.array_equal(subset, every[paths])


def test_grid_is_the_most_nearly_square_factorisation():
    assert [grid(n) for n in (1, 2, 8, 12, 16, 7, 64)] == [
        (1, 1),
        (1, 2),
        (2, 4),
        (3, 4),
        (4, 4),
        (1, 7),
        (8, 8),
    ]


def test_a_floor_under_the_sky_is_unbiased_and_less_noisy_stratified():
    """Every pixel of a diffuse floor under the sky sees the same integral: the stratified image's mean is
    it, and its pixels scatter less about it than independent samples' at the same spp."""
    scene = scene_with(
        [floor()],
        {"m": spec.Diffuse(reflectance=(0.5, 0.5, 0.5))},
        spec.EnvironmentMap(procedural="sky", params={"sun_elevation": 35.0}),
        camera=spec.Camera(
            position=(0, 3, 0.01), target=(0, 0, 0), up=(0, 0, -1), fov=30, width=32, height=32
        ),
    )
    tracer = PathTracer(compile_scene(scene))
    expected = reflected_by_a_floor(tracer)
    red = {
        sampler: render(tracer, RenderSettings(spp=16, max_depth=2, sampler=sampler)).image[..., 0].ravel()
        for sampler in ("independent", "stratified")
    }
    se = red["stratified"].std() / np.sqrt(red["stratified"].size)
    assert abs(red["stratified"].mean() - expected) < 4 * se
    assert red["stratified"].std() < 0.8 * red["independent"].std()
