"""G-buffers that follow mirrors (`primary_gbuffers(mirror_bounces=...)`, thesis Fig. 5.10): the pixels a
mirror covers describe the surface it shows, their throughput is the mirror's colour, and the pixel's
radiance is that throughput times the radiance leaving the surface (so training targets can be
demodulated by it); where the reflection escapes the mirror stays; every other pixel is untouched, and a
window is still the crop of the full frame."""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.explore.source import demodulated
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.render.integrator import PathTracer
from workers.scene.format.spec import Conductor, SceneSpec
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene

SIZE = 20
COLOUR = (0.8, 0.6, 0.4)
NAMES = ("position", "normal", "wo", "albedo", "roughness", "emission", "hit", "throughput")


def mirror_room(roughness: float) -> SceneSpec:
    """mirror_variable with its variables fixed and a coloured mirror of the given roughness."""
    spec = get_builtin("mirror_variable")
    materials = spec.materials | {"mirror": Conductor(roughness=roughness, specular=COLOUR)}
    return spec.model_copy(update={"materials": materials, "variables": []})


@pytest.fixture(scope="module")
def tracer() -> PathTracer:
    return PathTracer(compile_scene(mirror_room(0.0)))


@pytest.fixture(scope="module")
def camera(tracer) -> PinholeCamera:
    return PinholeCamera(tracer.scene.spec.camera, SIZE, SIZE)


def mirror_pixels(tracer: PathTracer, camera: PinholeCamera) -> np.ndarray:
    plain = primary_gbuffers(tracer, camera)
    return np.all(np.isclose(plain.albedo, COLOUR), axis=-1) & plain.hit


def test_mirror_pixels_see_the_reflected_surface_through_the_mirrors_colour(tracer, camera):
    plain, followed = primary_gbuffers(tracer, camera), primary_gbuffers(tracer, camera, mirror_bounces=1)
    mirror = mirror_pixels(tracer, camera)
    assert 20 < mirror.sum() < SIZE * SIZE - 20  # the view holds both
    for name in NAMES:
        theirs = np.ones_like(followed.throughput) if name == "throughput" else getattr(plain, name)
        np.testing.assert_array_equal(getattr(followed, name)[~mirror], theirs[~mirror], err_msg=name)
    # the reflected ray, computed here from the mirror's hit, reaches the buffers' surface
    ys, xs = np.nonzero(mirror)
    _, directions = camera.rays(xs + 0.5, ys + 0.5)
    n = plain.normal[mirror].astype(np.float64)
    reflected = directions - 2 * np.sum(directions * n, axis=1, keepdims=True) * n
    seen = tracer.first_hits(plain.position[mirror] + 1e-4 * reflected, reflected)
    hit = seen.hit
    assert 0 < hit.sum() < len(hit)  # the room, and the open front seen in the mirror
    # where the reflection escapes, the mirror stays the pixel's surface (emitting the black environment)
    assert followed.hit[mirror].all()
    for name in NAMES:
        theirs = np.ones_like(followed.throughput) if name == "throughput" else getattr(plain, name)
        np.testing.assert_array_equal(getattr(followed, name)[mirror][~hit], theirs[mirror][~hit], name)
    np.testing.assert_allclose(
        followed.throughput[mirror][hit], np.broadcast_to(COLOUR, (hit.sum(), 3)), 1e-6
    )
    np.testing.assert_allclose(followed.wo[mirror][hit], -reflected[hit], atol=1e-5)
    np.testing.assert_allclose(followed.position[mirror][hit], seen.position[hit], atol=1e-3)
    assert followed.albedo[mirror][hit].min() >= 0 and not np.isclose(followed.albedo[mirror], COLOUR).all()


def test_rough_conductors_are_not_followed():
    tracer = PathTracer(compile_scene(mirror_room(0.2)))
    camera = PinholeCamera(tracer.scene.spec.camera, SIZE, SIZE)
    followed = primary_gbuffers(tracer, camera, mirror_bounces=2)
    np.testing.assert_array_equal(followed.throughput, 1.0)
    np.testing.assert_array_equal(followed.position, primary_gbuffers(tracer, camera).position)


def test_a_mirror_whose_reflection_escaped_is_not_traced_again(tracer, camera, monkeypatch):
    """One flat mirror: after its reflection, no ray meets a mirror again, whatever `mirror_bounces`."""
    once = primary_gbuffers(tracer, camera, mirror_bounces=1)
    traced = []
    first_hits = tracer.first_hits
    monkeypatch.setattr(tracer, "first_hits", lambda o, d: traced.append(len(o)) or first_hits(o, d))
    thrice = primary_gbuffers(tracer, camera, mirror_bounces=3)
    assert len(traced) == 2, traced  # the camera's rays, then the mirror's reflections
    for name in NAMES:
        np.testing.assert_array_equal(getattr(thrice, name), getattr(once, name), err_msg=name)


def test_a_window_is_the_crop_of_the_full_frame_through_mirrors(tracer, camera):
    window = (3, 2, 17, 15)
    full, crop = (primary_gbuffers(tracer, camera, w, mirror_bounces=2) for w in (None, window))
    x0, y0, x1, y1 = window
    for name in NAMES:
        np.testing.assert_array_equal(getattr(crop, name), getattr(full, name)[y0:y1, x0:x1], err_msg=name)


def test_a_pixels_radiance_is_the_throughput_times_the_radiance_leaving_the_surface(tracer, camera):
    """In expectation over paths (a smooth mirror: the reflection is exact): the demodulated pixel equals
    the radiance arriving at the mirror point from the reflected direction, traced one segment shorter."""
    followed = primary_gbuffers(tracer, camera, mirror_bounces=1)
    plain = primary_gbuffers(tracer, camera)
    mirror = mirror_pixels(tracer, camera) & (followed.throughput != 1).any(axis=-1)  # reflections that land
    ys, xs = np.nonzero(mirror)
    origins, directions = camera.rays(xs + 0.5, ys + 0.5)
    reflected = -followed.wo[mirror].astype(np.float64)
    at_mirror = tracer.offset(plain.position[mirror], plain.normal[mirror], reflected)
    samples, depth = 256, 4
    rng = np.random.default_rng(5)
    pixel = np.stack([tracer.trace(origins, directions, rng, depth + 1).radiance for _ in range(samples)])
    leaving = np.stack([tracer.trace(at_mirror, reflected, rng, depth).radiance for _ in range(samples)])
    target = demodulated(pixel.mean(0), followed.throughput[mirror])
    a, b = target.mean(0), leaving.mean(0).mean(0)
    standard_error = np.sqrt(
        (pixel / followed.throughput[mirror]).mean(1).var(0, ddof=1) / samples
        + leaving.mean(1).var(0, ddof=1) / samples
    )
    assert np.all(np.abs(a - b) < 4 * standard_error + 1e-6), (a, b, standard_error)
    assert b.min() > 0.01  # the mirror shows a lit room
    # black where the mirror's colour is black, whatever the pixel
    assert demodulated(np.ones((2, 3)), np.array([[0.0, 0.5, 1.0], [1, 1, 1]])).tolist() == [
        [0, 2, 1],
        [1, 1, 1],
    ]
