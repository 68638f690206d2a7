"""Aggregate materials as path tracer plugins (`workers.render.aggregate_materials`), with a test double
for the family: the family registered under a material's type is built once per tracer with the scene's
used materials of that type and the camera at the rendered size; the surfaces keep the material's `base`
(an aggregate that never scatters leaves the image of the base material, bit for bit); a tracer given its
own aggregate refuses a scene that needs one built."""

from __future__ import annotations

import numpy as np
import pytest

from workers.render import aggregate_materials
from workers.render.aggregate import AggregateEvents
from workers.render.integrator import PathTracer
from workers.render.render import RenderSettings, render
from workers.scene.format.errors import SceneError
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import scene_from_dict

BASE = {"type": "plastic", "diffuse": [0.2, 0.6, 0.3], "roughness": 0.3}
built: list[tuple[dict, object]] = []


class Transparent:
    """An aggregate light passes through untouched: nothing scatters, nothing is blocked."""

    def first_events(self, origins, directions, t_min, t_max, rng) -> AggregateEvents:
        n = len(origins)
        return AggregateEvents(np.zeros(n, bool), np.full(n, np.inf), np.zeros((n, 3), np.int64), np.ones(n))

    def occluded(self, origins, directions, t_min, t_max) -> np.ndarray:
        return np.zeros(len(origins), bool)


def transparent(scene, materials, view) -> Transparent:
    built.append((materials, view))
    return Transparent()


@pytest.fixture
def family(monkeypatch):
    monkeypatch.setattr(aggregate_materials, "_families", {})
    aggregate_materials.register_aggregate_material("mesogan", f"{__name__}:transparent")
    built.clear()
    return built


def fur_ball(fur: dict) -> dict:
    data = get_builtin("fur_ball").model_dump(mode="json")
    data["materials"]["fur"] = fur
    data["materials"]["unused"] = {"type": "mesogan", "path": "elsewhere"}
    return data


def test_the_family_draws_the_used_materials_for_the_rendered_view_over_their_base(family):
    scene = compile_scene(scene_from_dict(fur_ball({"type": "mesogan", "path": "fur", "base": BASE})))
    settings = RenderSettings(spp=2, width=12, height=8, seed=4)
    image = render(scene, settings).image
    ((materials, view),) = family
    assert list(materials) == ["fur"] and materials["fur"].path == "fur"
    assert (view.width, view.height, view.fov) == (12, 8, scene.spec.camera.fov)
    base = render(compile_scene(scene_from_dict(fur_ball(BASE))), settings).image
    assert np.array_equal(image, base)


def test_a_tracer_with_its_own_aggregate_refuses_a_scene_that_needs_one_built(family):
    scene = compile_scene(scene_from_dict(fur_ball({"type": "mesogan", "path": "fur"})))
    with pytest.raises(SceneError) as error:
        PathTracer(scene, aggregate=Transparent())
    assert error.value.field == "materials.fur"
    assert family == []
