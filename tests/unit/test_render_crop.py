"""Crop-window rendering: G-buffers are exactly the crop of the full image's, radiance the crop in
expectation (Welch's t over independent seeds), and a window outside the image is an error naming it."""

from __future__ import annotations

import numpy as np
import pytest

from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SIZE = 24


@pytest.fixture(scope="module")
def tracer() -> PathTracer:
    return PathTracer(compile_scene(get_builtin("cornell_glossy")))


@pytest.mark.parametrize("window", [(5, 3, 17, 11), (0, 0, 1, 1), (SIZE - 4, SIZE - 7, SIZE, SIZE)])
def test_gbuffers_of_a_window_are_the_crop_of_the_full_ones(tracer, window):
    camera = PinholeCamera(tracer.scene.spec.camera, SIZE, SIZE)
    full, crop = primary_gbuffers(tracer, camera), primary_gbuffers(tracer, camera, window)
    x0, y0, x1, y1 = window
    for name in ("position", "normal", "wo", "albedo", "roughness", "emission", "hit"):
        np.testing.assert_array_equal(getattr(crop, name), getattr(full, name)[y0:y1, x0:x1], err_msg=name)


def test_gbuffers_at_points_in_each_pixel_are_a_finer_frames_centres(tracer):
    spec = tracer.scene.spec.camera
    camera, fine = PinholeCamera(spec, 8, 6), PinholeCamera(spec, 16, 12)
    grid = np.array([[0.25, 0.25], [0.75, 0.25], [0.25, 0.75], [0.75, 0.75]])  # 2 x 2, row-major
    points = primary_gbuffers(tracer, camera, (2, 1, 7, 5), grid)
    finer = primary_gbuffers(tracer, fine, (4, 2, 14, 10))
    for name in ("position", "normal", "albedo", "hit"):
        ours = getattr(points, name).reshape(4, 5, 2, 2, -1)  # rows, pixels, sample row, sample column
        theirs = getattr(finer, name).reshape(4, 2, 5, 2, -1).transpose(0, 2, 1, 3, 4)
        np.testing.assert_allclose(ours, theirs, atol=1e-5, err_msg=name)
    centres = primary_gbuffers(tracer, camera, None, np.array([[0.5, 0.5]]))
    np.testing.assert_array_equal(centres.position, primary_gbuffers(tracer, camera).position)


def test_a_window_renders_the_crop_of_the_full_image_in_expectation(tracer):
    window = (6, 2, 20, 14)  # the light, a glossy sphere's highlight and the caustic
    x0, y0, x1, y1 = window
    seeds = range(6)
    settings = RenderSettings(spp=16, width=SIZE, height=SIZE, max_depth=5, tile_size=8)
    full = [render(tracer, settings.model_copy(update={"seed": s})).image[y0:y1, x0:x1] for s in seeds]
    crop = [
        render(tracer, settings.model_copy(update={"seed": 100 + s, "window": window})).image for s in seeds
    ]
    assert crop[0].shape == (y1 - y0, x1 - x0, 3)
    a, b = np.array([f.mean(axis=(0, 1)) for f in full]), np.array([c.mean(axis=(0, 1)) for c in crop])
    t = (a.mean(0) - b.mean(0)) / np.sqrt(a.var(0, ddof=1) / len(a) + b.var(0, ddof=1) / len(b))
    assert np.all(np.abs(t) < 4.5), t
    # per pixel, the mean over seeds agrees within the noise too (few pixels far out)
    pa, pb = np.stack(full), np.stack(crop)
    z = (pa.mean(0) - pb.mean(0)) / np.sqrt(pa.var(0, ddof=1) / len(pa) + pb.var(0, ddof=1) / len(pb) + 1e-12)
    assert np.mean(np.abs(z) > 4) < 0.02


def test_a_window_outside_the_image_is_an_error_naming_it(tracer):
    with pytest.raises(ValueError, match=r"^window: "):
        render(tracer, RenderSettings(spp=1, width=8, height=8, window=(4, 4, 9, 6)))
    with pytest.raises(ValueError, match=r"^window: "):
        primary_gbuffers(tracer, PinholeCamera(tracer.scene.spec.camera, 8, 8), (3, 3, 3, 5))


def test_centre_samples_see_what_the_gbuffers_describe(tracer):
    """`pixel_samples="centre"` traces every path through the pixel's centre: its first hits are the
    G-buffers' at every pixel, edges included, where area samples mix the surfaces a pixel covers."""
    camera = PinholeCamera(tracer.scene.spec.camera, SIZE, SIZE)
    buffers = primary_gbuffers(tracer, camera)
    settings = RenderSettings(spp=4, width=SIZE, height=SIZE, max_depth=2, aovs=True, pixel_samples="centre")
    centre = render(tracer, settings).aovs["position"]
    np.testing.assert_allclose(centre, buffers.position, atol=1e-5)
    area = render(tracer, settings.model_copy(update={"pixel_samples": "area"})).aovs["position"]
    assert np.abs(area - buffers.position).max() > 0.1  # at the edges
