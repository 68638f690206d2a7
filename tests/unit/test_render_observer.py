"""Path events: escapes account for all of the environment's light, and observing changes nothing traced."""

from __future__ import annotations

import numpy as np
import pytest

from workers.render.aggregate import AggregateEvents
from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer
from workers.render.observer import PathObserver
from workers.scene.format import spec
from workers.scene.geometry.compile import compile_scene

BOX = np.array([[0.4, 0.0, -0.3], [1.0, 0.6, 0.3]])


class BoxAggregate:
    """One voxel, the box BOX, scattering every ray that enters it with a constant throughput phi."""

    def __init__(self, phi: float):
        self.phi = phi

    @staticmethod
    def _slab(origins, directions):
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (BOX[0] - origins) / directions, (BOX[1] - origins) / directions
        return np.minimum(t0, t1).max(1), np.maximum(t0, t1).min(1)

    def first_events(self, origins, directions, t_min, t_max, rng):
        near, far = self._slab(origins, directions)
        near = np.maximum(near, t_min)
        found = (far >= near) & (near < t_max)
        n = len(origins)
        return AggregateEvents(found, np.where(found, near, np.inf), np.zeros((n, 3), np.int64), np.ones(n))

    def occluded(self, origins, directions, t_min, t_max):
        near, far = self._slab(origins, directions)
        return np.minimum(far, t_max) > np.maximum(near, t_min)

    def throughput(self, voxel, wo, wi):
        return np.full((len(voxel), 3), self.phi)

    def exit_distance(self, voxel, origins, directions):
        return np.maximum(self._slab(origins, directions)[1], 0.0)


class Recorder(PathObserver):
    """Sums weight x environment radiance of every escape per traced ray, and keeps the other events."""

    def __init__(self, tracer: PathTracer, n: int):
        self.environment = tracer.lights.environment
        self.escaped = np.zeros((n, 3))
        self.first_surface = np.full((n, 3), np.nan)
        self.aggregate_positions = []

    def on_escape(self, idx, directions, weight):
        assert len(np.unique(idx)) == len(idx)
        self.escaped[idx] += weight * self.environment.radiance(directions)

    def on_surface(self, idx, position, normal, beta):
        first = np.isnan(self.first_surface[idx, 0])
        self.first_surface[idx[first]] = position[first]

    def on_aggregate(self, idx, position, voxel, beta):
        self.aggregate_positions.append(position)


def sky_scene(lights=()) -> spec.SceneSpec:
    """A diffuse floor, a plastic ball and a rough metal ball under a procedural sky."""
    return spec.SceneSpec(
        materials={
            "floor": spec.Diffuse(reflectance=(0.6, 0.5, 0.4)),
            "plastic": spec.Plastic(diffuse=(0.7, 0.1, 0.1), roughness=0.2),
            "metal": spec.Conductor(roughness=0.3, specular=(0.9, 0.8, 0.6)),
        },
        objects=[
            spec.SceneObject(
                name="floor", shape=spec.RectangleShape(), material="floor",
                transform=spec.Transform(rotate=(-90, 0, 0), scale=3.0),
            ),
            spec.SceneObject(
                name="ball", shape=spec.SphereShape(center=(-0.5, 0.4, 0), radius=0.4, subdivisions=4),
                material="plastic",
            ),
            spec.SceneObject(
                name="metal", shape=spec.SphereShape(center=(0.1, 0.25, 0.6), radius=0.25, subdivisions=4),
                material="metal",
            ),
        ],
        environment=spec.EnvironmentMap(procedural="sky"),
        lights=list(lights),
        camera=spec.Camera(position=(0, 1.2, 3), target=(0, 0.3, 0), width=48, height=32, fov=50),
    )  # fmt: skip


def camera_rays(scene: spec.SceneSpec, spp: int = 4):
    camera = PinholeCamera(scene.camera, scene.camera.width, scene.camera.height)
    ys, xs = np.mgrid[0 : camera.height, 0 : camera.width]
    jitter = np.random.default_rng(7).random((camera.height * camera.width * spp, 2))
    return camera.rays(np.repeat(xs.ravel(), spp) + jitter[:, 0], np.repeat(ys.ravel(), spp) + jitter[:, 1])


@pytest.mark.parametrize("aggregate", [None, BoxAggregate(0.3 / (4 * np.pi))], ids=["surfaces", "aggregate"])
def test_escapes_weighted_by_environment_radiance_sum_to_the_traced_radiance(aggregate):
    """Lit by the sky alone, each path's radiance is sum over its escapes of weight x L_env(direction):
    BSDF-sampled escapes (MIS-weighted) and light samples of the sky, from surfaces and from the
    aggregate. Missing either kind, or a MIS weight, breaks the identity path by path."""
    scene = sky_scene()
    tracer = PathTracer(compile_scene(scene), aggregate=aggregate)
    origins, directions = camera_rays(scene)
    recorder = Recorder(tracer, len(origins))
    result = tracer.trace(
        origins, directions, np.random.default_rng(1), max_depth=6, rr_depth=3, observer=recorder
    )
    assert result.radiance.mean() > 0.05 and (result.bounces > 3).any()
    np.testing.assert_allclose(recorder.escaped, result.radiance, rtol=1e-9, atol=1e-12)
    if aggregate is not None:
        positions = np.concatenate(recorder.aggregate_positions)
        assert len(positions) > 100
        # Where rays enter the voxel, or start in it (from the floor, which is the box's bottom face).
        assert np.all((positions >= BOX[0] - 1e-6) & (positions <= BOX[1] + 1e-6))


def test_the_first_surface_event_is_the_first_hit():
    scene = sky_scene()
    tracer = PathTracer(compile_scene(scene))
    origins, directions = camera_rays(scene, spp=1)
    recorder = Recorder(tracer, len(origins))
    tracer.trace(origins, directions, np.random.default_rng(2), observer=recorder)
    records = tracer.first_hits(origins, directions)
    assert records.hit.mean() > 0.5
    np.testing.assert_array_equal(np.isnan(recorder.first_surface[:, 0]), ~records.hit)
    np.testing.assert_array_equal(recorder.first_surface[records.hit], records.position[records.hit])


def test_observing_changes_nothing_traced():
    """No observer, one that does nothing and one that records: the same radiance, bit for bit."""
    scene = sky_scene(lights=[spec.PointLight(position=(0.5, 2.0, 1.0), intensity=(3.0, 3.0, 3.0))])
    tracer = PathTracer(compile_scene(scene), aggregate=BoxAggregate(0.2 / (4 * np.pi)))
    origins, directions = camera_rays(scene, spp=2)
    results = [
        tracer.trace(origins, directions, np.random.default_rng(3), observer=observer)
        for observer in (None, PathObserver(), Recorder(tracer, len(origins)))
    ]
    for other in results[1:]:
        np.testing.assert_array_equal(other.radiance, results[0].radiance)
        np.testing.assert_array_equal(other.bounces, results[0].bounces)
        assert other.rays_traced == results[0].rays_traced
