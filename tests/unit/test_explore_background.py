"""Camera rays that escape show the environment: their G-buffers carry its radiance along the ray, the
explore network passes it through whatever its weights, and so frames of any network show the background
exactly as path tracing does, at every rotation of the environment. A mirror whose reflection escapes
emits the environment it reflects. Before this, an escaped pixel's buffers were all zero and the network
painted the background a constant it had to learn (a flat grey in the mirror of `mirror_variable` with
`mirror_bounces`, where reflections escaped the room)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from workers.models.explore.config import PRESETS, ExploreConfig
from workers.models.explore.evaluate import network_image
from workers.models.explore.features import BUFFER_CHANNELS
from workers.models.explore.network import PixelGenerator
from workers.models.explore.source import PatchRequest, PatchSource, PatchSourceConfig
from workers.render.camera import PinholeCamera
from workers.render.gbuffer import primary_gbuffers
from workers.scene.format.spec import (
    Camera,
    Conductor,
    EnvironmentMap,
    EnvironmentRotationVariable,
    SceneSpec,
)
from workers.scene.generators.builtin import get_builtin
from workers.scene.portability.reference import SceneRef

SIZE = 24
SUN_AHEAD = {"sun_elevation": 10.0, "sun_azimuth": 0.0, "sun_irradiance": 1.0}  # its glow turns with the sky
CONFIG = ExploreConfig.model_validate(PRESETS["quick"]).model_copy(update={"mirror_bounces": 1})


def room_under_a_sky() -> SceneSpec:
    """mirror_variable with a perfect mirror, under a procedural sky that turns (the last dimension),
    seen from far enough back that the sky shows around the room and in the mirror through its open front."""
    spec = get_builtin("mirror_variable")
    return spec.model_copy(
        update={
            "materials": spec.materials | {"mirror": Conductor(roughness=0.0, specular=(0.9, 0.9, 0.9))},
            "environment": EnvironmentMap(procedural="sky", params=SUN_AHEAD),
            "camera": Camera(position=(1.5, 0.6, 6.0), target=(-0.2, -0.3, -1.0), fov=45.0),
            "variables": [
                *spec.variables,
                EnvironmentRotationVariable(name="sky", min_angle=0.0, range_angle=180.0),
            ],
        }
    )


@pytest.fixture(scope="module")
def source() -> PatchSource:
    return PatchSource(PatchSourceConfig(SceneRef(room_under_a_sky()), CONFIG), seed=0)


def at(sky: float) -> np.ndarray:
    """The scene vector with the box and the light in the middle and the sky turned by `sky`."""
    return np.array([0.5, 0.5, 0.5, sky])


def random_network(source: PatchSource) -> PixelGenerator:
    torch.manual_seed(1)
    return PixelGenerator.of(CONFIG, source.dimensions)


def traced_through_centres(tracer, pinhole: PinholeCamera) -> np.ndarray:
    """One path per pixel centre: where the camera ray escapes (directly or off a perfect mirror), its
    radiance is exactly the environment's, whatever the random numbers."""
    ys, xs = np.mgrid[0 : pinhole.height, 0 : pinhole.width]
    origins, directions = pinhole.rays(xs.ravel() + 0.5, ys.ravel() + 0.5)
    radiance = tracer.trace(origins, directions, np.random.default_rng(0), 3).radiance
    return radiance.reshape(pinhole.height, pinhole.width, 3)


@pytest.mark.parametrize("sky", [0.0, 0.7])
def test_escaped_pixels_of_frames_are_the_environment_path_tracing_sees(source, sky):
    v = at(sky)
    tracer = source.tracer.at(v)
    camera = tracer.scene.spec.camera
    pinhole = PinholeCamera(camera, SIZE, SIZE)
    plain, followed = primary_gbuffers(tracer, pinhole), primary_gbuffers(tracer, pinhole, mirror_bounces=1)
    background = ~plain.hit
    np.testing.assert_array_equal(followed.hit, plain.hit)
    in_mirror = (followed.emission != plain.emission).any(axis=-1)  # the mirror, emitting the sky it shows
    assert background.sum() > 20 and in_mirror.sum() > 5
    frame, _ = network_image(random_network(source), tracer, camera, source.box, v, SIZE, SIZE, 1, 1)
    exact = traced_through_centres(tracer, pinhole)
    assert exact[background].min() > 0.05  # a lit sky, not the black a zero-buffer network could match
    np.testing.assert_allclose(frame[background], exact[background], rtol=1e-4, atol=1e-6)
    # a perfect mirror adds nothing to the sky it reflects: its emission is the pixel's radiance
    np.testing.assert_array_equal(followed.throughput[in_mirror], 1.0)
    np.testing.assert_allclose(followed.emission[in_mirror], exact[in_mirror], rtol=1e-4)


def test_the_sky_turns_with_its_variable(source):
    frames = []
    for sky in (0.0, 1.0):
        v = at(sky)
        tracer = source.tracer.at(v)
        frames.append(primary_gbuffers(tracer, PinholeCamera(tracer.scene.spec.camera, SIZE, SIZE)).emission)
    assert np.abs(frames[0] - frames[1]).max() > 0.05


def test_the_network_passes_escaped_pixels_through_and_learns_nothing_from_them(source):
    request = PatchRequest(tuple(at(0.3)), 32, 4, 4, seed=3)  # the sky around the room, and the room
    patch = source.render(request)
    model = random_network(source)
    prediction = model(patch["features"], patch["emission"])
    escaped = (patch["features"][..., :BUFFER_CHANNELS] == 0).all(dim=-1)
    assert 0 < escaped.float().mean() < 1
    torch.testing.assert_close(prediction[escaped], torch.log1p(patch["emission"][escaped]))
    # the patch's target there is the sky over each pixel's area: close to the buffers' value at its centre
    sky = patch["emission"][escaped]
    np.testing.assert_allclose(patch["target"][escaped].mean(0), sky.mean(0), rtol=0.05)
    prediction[escaped].sum().backward()
    assert all(p.grad is None or p.grad.abs().max() == 0 for p in model.parameters())
