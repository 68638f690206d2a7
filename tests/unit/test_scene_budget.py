"""Triangle counts from parameters alone: exact for every deterministic generator, an upper bound for the
random one, and the limit refuses a scene before the object that crosses it is built."""

import time
import tracemalloc

import pytest

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators.catalogue import GENERATORS, generate, generated_triangles
from workers.scene.geometry.budget import MAX_SCENE_TRIANGLES_ENV, scene_triangles, shape_triangles
from workers.scene.geometry.compile import compile_scene
from workers.scene.geometry.shapes import shape_mesh

EXACT = {
    "ground_plane": [{}],
    "fractal_tree": [
        {"depth": 3, "branching": 2, "parts": "leaves"},
        {"depth": 2, "parts": "branches"},
        {"depth": 4, "leaves_per_tip": 0, "sides": 7},
    ],
    "displaced_sphere": [{"resolution": 24}, {"resolution": 4}],
    "fur": [{"strands": 50, "segments": 3, "sides": 4}],
    "menger_sponge": [{"level": level} for level in range(4)],
    "hollow_box": [{}],
    "mesoscale_slab": [{}, {"material": "carpet", "tiles": 1, "structure": {"density": 5.0}}],
    "mesoscale_base": [{}],
}
BOUNDED = {"thin_wall_rooms": [{}, {"cells_x": 1, "cells_y": 1, "cells_z": 1, "windows": 1.0, "doors": 1.0}]}
# the validators' maxima, each far over any sensible limit: refused in milliseconds, never built
MAXIMA = {
    "fractal_tree": {"depth": 10, "branching": 6, "leaves_per_tip": 200, "sides": 16},
    "displaced_sphere": {"resolution": 2000},
    "fur": {"strands": 200_000, "segments": 16, "sides": 8},
    "menger_sponge": {"level": 5},
    "mesoscale_slab": {"structure": {"density": 400}, "tile": 1000.0, "tiles": 9},
}


def test_every_generator_has_a_count_case():
    assert set(GENERATORS) == set(EXACT) | set(BOUNDED)


@pytest.mark.parametrize(("name", "params"), [(n, p) for n, ps in EXACT.items() for p in ps])
def test_counts_are_exact(name, params):
    assert generated_triangles(name, params, "x") == generate(name, params, "x").num_triangles


@pytest.mark.parametrize(("name", "params"), [(n, p) for n, ps in BOUNDED.items() for p in ps])
def test_random_layouts_stay_under_their_bound(name, params):
    bound = generated_triangles(name, params, "x")
    made = [generate(name, {**params, "seed": seed}, "x").num_triangles for seed in range(3)]
    assert max(made) <= bound < 10 * max(made)


@pytest.mark.parametrize("name", sorted(MAXIMA))
def test_validator_maxima_are_refused_before_building(name):
    tracemalloc.start()
    started = time.process_time()
    with pytest.raises(SceneError) as caught:
        generate(name, MAXIMA[name], "objects[0].shape", max_triangles=8_000_000)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert caught.value.field == "objects[0].shape.params"
    assert "over the limit of 8,000,000" in caught.value.problem
    assert peak < 1 << 20 and time.process_time() - started < 0.5


def test_analytic_shapes_count_like_their_meshes():
    for shape in (spec.RectangleShape(), spec.BoxShape(), spec.SphereShape(subdivisions=3)):
        assert shape_triangles(shape, "s") == shape_mesh(shape, "s").num_triangles


def scene_with(obj: spec.SceneObject) -> spec.SceneSpec:
    light = spec.PointLight(position=(0, 5, 0), intensity=(1, 1, 1))
    return spec.SceneSpec(materials={"m": spec.Diffuse()}, objects=[obj], lights=[light])


def test_instances_count_against_the_limit_and_are_named(monkeypatch):
    tree = spec.ProceduralShape(generator="fractal_tree", params={"depth": 4})
    many = spec.SceneObject(
        name="forest",
        shape=tree,
        material="m",
        instances=[spec.Transform(translate=(i, 0, 0)) for i in range(20_000)],
    )
    per_tree = generated_triangles("fractal_tree", {"depth": 4}, "x")
    with pytest.raises(SceneError) as caught:
        scene_triangles(scene_with(many), limit=8_000_000)
    assert caught.value.field == "objects[0].instances"
    assert f"{20_000 * per_tree:,} triangles" in caught.value.problem
    monkeypatch.setenv(MAX_SCENE_TRIANGLES_ENV, "1000")
    with pytest.raises(SceneError) as caught:
        compile_scene(scene_with(many))
    assert caught.value.field == "objects[0].instances"


def test_compile_refuses_a_mesh_file_over_the_limit_after_reading_it(tmp_path):
    import trimesh

    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "ball.ply")
    ball = spec.SceneObject(name="ball", shape=spec.MeshShape(path="ball.ply"), material="m")
    assert compile_scene(scene_with(ball), tmp_path, max_triangles=320).num_triangles == 320
    with pytest.raises(SceneError) as caught:
        compile_scene(scene_with(ball), tmp_path, max_triangles=319)
    assert caught.value.field == "objects[0].shape"
