"""Region probes: rays start on the region's boundary, point inside, and are cosine-distributed."""

import numpy as np
import pytest

from workers.render.integrator import PathTracer
from workers.render.region_rays import rays_entering_box, rays_from_bounding_sphere
from workers.scene.builtin import cornell_box
from workers.scene.compile import compile_scene

BOX = np.array([[-0.5, -1.0, 0.0], [0.5, 1.0, 0.25]])


def test_rays_entering_box_start_on_faces_and_point_inwards():
    o, d = rays_entering_box(BOX, 50_000, np.random.default_rng(0))
    on_face = np.isclose(o, BOX[0]) | np.isclose(o, BOX[1])
    assert on_face.any(axis=1).all()
    assert np.all((o >= BOX[0] - 1e-12) & (o <= BOX[1] + 1e-12))
    inside_soon = o + 1e-6 * d
    assert np.all((inside_soon >= BOX[0]) & (inside_soon <= BOX[1]))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)


def test_face_choice_is_area_weighted_and_directions_cosine_distributed():
    o, d = rays_entering_box(BOX, 200_000, np.random.default_rng(1))
    on_y_face = np.isclose(o[:, 1], BOX[0, 1]) | np.isclose(o[:, 1], BOX[1, 1])
    size = BOX[1] - BOX[0]
    areas = np.array([size[1] * size[2], size[0] * size[2], size[0] * size[1]])
    assert on_y_face.mean() == pytest.approx(areas[1] / areas.sum(), abs=0.005)
    cos = np.abs(d[on_y_face, 1])
    assert cos.mean() == pytest.approx(2 / 3, abs=0.005)  # E[cos] under a cosine lobe


def test_sphere_rays_start_on_the_circumscribed_sphere_and_head_inwards():
    o, d = rays_from_bounding_sphere(BOX, 20_000, np.random.default_rng(2))
    centre, radius = BOX.mean(0), 0.5 * np.linalg.norm(BOX[1] - BOX[0])
    np.testing.assert_allclose(np.linalg.norm(o - centre, axis=1), radius, rtol=1e-9)
    assert np.all(np.einsum("ij,ij->i", d, centre - o) > 0)


def test_sample_region_finds_the_small_box_and_returns_finite_radiance():
    tracer = PathTracer(compile_scene(cornell_box()))
    region = np.array([[0.0, -1.0, 0.0], [0.7, -0.35, 0.75]])  # around the small box
    samples = tracer.sample_region(region, 4000, np.random.default_rng(3), max_depth=4)
    assert samples.inside.mean() > 0.3
    names = [o.name for o in tracer.scene.objects]
    hit_objects = {names[i] for i in samples.records.object_id[samples.inside]}
    assert "small_box" in hit_objects
    assert np.isfinite(samples.radiance).all() and (samples.radiance >= 0).all()
