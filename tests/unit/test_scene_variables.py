"""Variable scenes: validation naming the field, `SceneSpec.at(v)`, the compiled scene at v (static
geometry compiled and put in a BVH once) and vector encoding for serving."""

from __future__ import annotations

import numpy as np
import pytest

from workers.render.render import RenderSettings, render
from workers.render.variable_tracer import VariableTracer
from workers.scene.format.errors import SceneError
from workers.scene.format.variables import dimension_names, switch_index, vector_from_values
from workers.scene.generators.builtin import get_builtin
from workers.scene.geometry import compile as compile_module
from workers.scene.geometry.compile import compile_scene
from workers.scene.geometry.variable_scene import CompiledVariableScene
from workers.scene.portability.io import scene_from_dict


def cornell(variables: list[dict], **extra) -> dict:
    data = get_builtin("cornell_box").model_dump(mode="json") | extra
    data["variables"] = variables
    return data


@pytest.mark.parametrize(
    ("variable", "field", "words"),
    [
        (
            {"type": "translate", "name": "a", "object": "nope", "max": [1, 0, 0]},
            "variables[0].object",
            "unknown object",
        ),
        (
            {"type": "translate", "name": "a", "object": "small_box", "max": [0, 0, 0]},
            "variables[0].max",
            "empty",
        ),
        (
            {"type": "rotate", "name": "a", "object": "small_box", "range_angle": 0},
            "variables[0].range_angle",
            "empty",
        ),
        (
            {"type": "albedo", "name": "a", "material": "gold", "min": [0, 0, 0], "max": [1, 1, 1]},
            "variables[0].material",
            "unknown material",
        ),
        (
            {"type": "roughness", "name": "a", "material": "white", "min": 0.1, "max": 0.2},
            "variables[0].material",
            "no roughness",
        ),
        (
            {"type": "albedo", "name": "a", "material": "white", "min": [0, 0, 0], "max": [1.5, 1, 1]},
            "variables[0].max[0]",
            "less than or equal",
        ),
        (
            {"type": "light_intensity", "name": "a", "light": "lights[3]", "min": 0, "max": 1},
            "variables[0].light",
            "unknown light",
        ),
        (
            {"type": "light_intensity", "name": "a", "light": "floor", "min": 0, "max": 1},
            "variables[0].light",
            "emits no light",
        ),
        (
            {"type": "environment_rotation", "name": "a", "range_angle": 90},
            "variables[0].type",
            "no environment",
        ),
        (
            {"type": "switch", "name": "a", "objects": ["small_box", "small_box"]},
            "variables[0].objects",
            "twice",
        ),
        (
            {
                "type": "camera",
                "name": "c",
                "position_min": [0, 0, 2],
                "position_max": [0, 0, 4],
                "target_min": [0, 0, 3],
                "target_max": [0, 0, 3.5],
            },
            "variables[0].target_min",
            "look at itself",
        ),
    ],
)
def test_bad_variables_are_errors_naming_the_field(variable, field, words):
    with pytest.raises(SceneError) as error:
        scene_from_dict(cornell([variable]))
    assert error.value.field == field, error.value
    assert words in error.value.problem


def test_a_constant_background_has_no_map_to_rotate():
    rotation = {"type": "environment_rotation", "name": "a", "range_angle": 90}
    with pytest.raises(SceneError) as error:
        scene_from_dict(cornell([rotation], environment={"type": "constant", "radiance": [0.5, 0.5, 0.5]}))
    assert error.value.field == "variables[0].type", error.value
    assert "no environment map" in error.value.problem


def test_a_range_that_makes_the_scene_invalid_at_one_end_names_the_variable():
    # A camera that looks along its up vector at one end of its range is invalid only there.
    variable = {
        "type": "camera",
        "name": "c",
        "position_min": [0, 0, 3.9],
        "position_max": [0, 0, 4.0],
        "target_min": [0, 0, 0],
        "target_max": [0, 0, 0],
    }
    ok = scene_from_dict(cornell([variable]))
    assert ok.dimensions == 1
    looking_up = dict(variable, target_min=[0, 5, 3.9], target_max=[0, 6, 3.9], position_min=[0, 0, 3.9],
                      position_max=[0, 0.5, 3.9])  # fmt: skip
    with pytest.raises(SceneError) as error:
        scene_from_dict(cornell([looking_up]))
    assert error.value.field.startswith("variables"), error.value
    duplicate = [
        {"type": "roughness", "name": "r", "material": "metal", "min": 0.1, "max": 0.2},
        {"type": "roughness", "name": "r", "material": "metal", "min": 0.1, "max": 0.3},
    ]
    with pytest.raises(SceneError) as error:
        scene_from_dict(
            cornell(duplicate, materials={"metal": {"type": "conductor"}, **cornell([])["materials"]})
        )
    assert error.value.field == "variables[1].name"


def test_at_maps_each_dimension_onto_its_range():
    scene = get_builtin("cornell_variable")
    names = dimension_names(scene)
    v = np.linspace(0.0, 1.0, scene.dimensions)
    concrete = scene.at(v)
    assert concrete.variables == []
    red = concrete.materials["red"].reflectance
    lo, hi = (0.2, 0.02, 0.02), (0.9, 0.4, 0.3)
    assert red == pytest.approx([lo[i] + v[i] * (hi[i] - lo[i]) for i in range(3)])
    roughness = concrete.materials["metal"].roughness
    assert roughness == pytest.approx(0.02 + v[names.index("sphere_roughness")] * 0.48)
    box = {o.name: o for o in concrete.objects}["small_box"].transform.to_matrix()
    base = {o.name: o for o in scene.objects}["small_box"].transform.to_matrix()
    vx, vz = v[names.index("box.x")], v[names.index("box.z")]
    assert box[:3, 3] - base[:3, 3] == pytest.approx([-0.25 + vx * 0.45, 0.0, -0.3 + vz * 0.55])
    assert np.allclose(box[:3, :3], base[:3, :3])
    with pytest.raises(ValueError, match=r"^v: "):
        scene.at(np.full(scene.dimensions, 1.5))
    with pytest.raises(ValueError, match=r"^v: "):
        scene.at([0.5])


def test_a_switch_at_one_picks_the_last_alternative():
    assert [switch_index(u, 3) for u in (0.0, 0.33, 0.34, 0.99, 1.0)] == [0, 0, 1, 2, 2]
    data = cornell([{"type": "switch", "name": "which", "objects": ["small_box", "large_box"]}])
    scene = scene_from_dict(data)
    names = lambda v: {o.name for o in scene.at([v]).objects}  # noqa: E731
    assert "large_box" in names(1.0) and "small_box" not in names(1.0)
    assert "small_box" in names(0.0) and "large_box" not in names(0.0)


def test_the_compiled_scene_at_v_matches_compiling_the_concrete_scene():
    scene = get_builtin("cornell_variable")
    compiled = CompiledVariableScene(scene)
    for seed in range(3):
        v = np.random.default_rng(seed).random(scene.dimensions)
        state = compiled.at(v).compiled
        direct = compile_scene(scene.at(v))
        np.testing.assert_allclose(state.positions, direct.positions, atol=1e-6)
        np.testing.assert_allclose(state.shading_normals, direct.shading_normals, atol=1e-6)
        np.testing.assert_array_equal(state.emission, direct.emission)
        assert state.materials == direct.materials
        a = render(VariableTracer(compiled).at(v), RenderSettings(spp=2, width=16, height=16))
        b = render(direct, RenderSettings(spp=2, width=16, height=16))
        np.testing.assert_allclose(a.image, b.image, rtol=1e-4, atol=1e-5)


def test_static_geometry_is_loaded_and_put_in_a_bvh_once(monkeypatch):
    scene = get_builtin("cornell_variable")
    compiled = CompiledVariableScene(scene)
    tracer = VariableTracer(compiled)
    calls = []
    monkeypatch.setattr(compile_module, "shape_mesh", lambda *a: calls.append(a))
    first, second = tracer.at(np.zeros(scene.dimensions)), tracer.at(np.ones(scene.dimensions))
    assert calls == []
    assert first.rays.static is second.rays.static is tracer.static
    moved = {compiled.base.objects[i].name for i in compiled.moved}
    assert moved == {"small_box", "light"}
    static = compiled.static_triangles
    np.testing.assert_array_equal(
        compiled.at(np.zeros(scene.dimensions)).compiled.positions[static], compiled.base.positions[static]
    )


def test_hidden_alternatives_are_neither_hit_nor_lit():
    data = cornell([{"type": "switch", "name": "lamp", "objects": ["light", "small_box"]}])
    compiled = CompiledVariableScene(scene_from_dict(data))
    dark = compiled.at([1.0]).compiled  # the box, not the light
    assert not dark.emission.any()
    image = render(VariableTracer(compiled).at([1.0]), RenderSettings(spp=2, width=8, height=8)).image
    assert image.max() == 0.0
    lit = render(VariableTracer(compiled).at([0.0]), RenderSettings(spp=2, width=8, height=8)).image
    assert lit.max() > 0.0


def test_values_by_name_in_their_units_or_normalised():
    scene = get_builtin("cornell_variable")
    names = dimension_names(scene)
    v = vector_from_values(scene, {"sphere_roughness": 0.26, "box": [-0.25, 0.0, 0.25]})
    assert v[names.index("sphere_roughness")] == pytest.approx(0.5)
    assert v[names.index("box.x")] == pytest.approx(0.0) and v[names.index("box.z")] == pytest.approx(1.0)
    assert v[names.index("light.x")] == 0.5  # not named: the middle of its range
    assert vector_from_values(scene, {"light": [0.25, 0.75]}, normalised=True)[names.index("light.z")] == 0.75
    with pytest.raises(ValueError, match=r"^values\.nope: unknown"):
        vector_from_values(scene, {"nope": 1})
    with pytest.raises(ValueError, match=r"^values\.sphere_roughness: outside"):
        vector_from_values(scene, {"sphere_roughness": 0.9})


def test_every_variable_type_sets_its_field():
    data = cornell(
        [
            {"type": "rotate", "name": "turn", "object": "small_box", "pivot": [0.3, 0, 0.3],
             "min_angle": -30, "range_angle": 60},
            {"type": "light_intensity", "name": "dim", "light": "light", "min": 0.0, "max": 2.0},
            {"type": "light_color", "name": "lamp", "light": "lights[0]", "min": [1, 1, 1], "max": [3, 1, 1]},
            {"type": "light_position", "name": "lamp_x", "light": "lights[0]", "max": [0.5, 0, 0]},
            {"type": "specular", "name": "gold", "material": "metal", "min": [0.5, 0.5, 0.5],
             "max": [1, 0.8, 0.5]},
            {"type": "environment_rotation", "name": "sky", "range_angle": 180},
            {"type": "camera", "name": "view", "position_min": [-0.5, 0, 3], "position_max": [0.5, 0, 4],
             "target_min": [0, 0, 0], "target_max": [0, 0.5, 0]},
            {"type": "switch", "name": "which", "objects": ["small_box", "large_box"]},
        ],
        lights=[{"type": "point", "position": [0, 0.5, 0], "intensity": [1, 1, 1]}],
        environment={"type": "envmap", "procedural": "sky"},
    )  # fmt: skip
    data["materials"]["metal"] = {"type": "conductor"}
    scene = scene_from_dict(data)
    names = dimension_names(scene)
    assert names == [
        "turn", "dim", "lamp.r", "lamp_x.x", "gold.r", "gold.g", "sky",
        "view.position.x", "view.position.z", "view.target.y", "which",
    ]  # fmt: skip
    v = np.array([0.75, 0.25, 0.5, 1.0, 1.0, 0.5, 0.5, 0.0, 1.0, 1.0, 0.0])
    concrete = scene.at(v)
    box = {o.name: o for o in concrete.objects}["small_box"].transform.to_matrix()
    base = {o.name: o for o in scene.objects}["small_box"].transform.to_matrix()
    turn = np.radians(-30 + 0.75 * 60)
    rotation = np.array([[np.cos(turn), 0, np.sin(turn)], [0, 1, 0], [-np.sin(turn), 0, np.cos(turn)]])
    pivot = np.array([0.3, 0, 0.3])
    np.testing.assert_allclose(box[:3, :3], rotation @ base[:3, :3], atol=1e-12)
    np.testing.assert_allclose(box[:3, 3], rotation @ (base[:3, 3] - pivot) + pivot, atol=1e-12)
    light = {o.name: o for o in concrete.objects}["light"]
    original = {o.name: o for o in scene.objects}["light"].emission
    assert light.emission == pytest.approx([0.5 * c for c in original])
    assert concrete.lights[0].intensity == pytest.approx((2.0, 1.0, 1.0))
    assert concrete.lights[0].position == pytest.approx((0.5, 0.5, 0.0))
    assert concrete.materials["metal"].specular == pytest.approx((1.0, 0.65, 0.5))
    assert concrete.environment.rotate == pytest.approx((0.0, 90.0, 0.0))
    assert concrete.camera.position == pytest.approx((-0.5, 0.0, 4.0))
    assert concrete.camera.target == pytest.approx((0.0, 0.5, 0.0))
    assert "large_box" not in {o.name for o in concrete.objects}
    state = CompiledVariableScene(scene).at(v).compiled
    np.testing.assert_allclose(state.environment_rotation, compile_scene(concrete).environment_rotation)
