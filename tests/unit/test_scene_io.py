"""Scene loading: built-in names, YAML/JSON files, dicts; every bad input names its field and problem."""

import copy
import json

import numpy as np
import pytest
import trimesh
from pydantic import ValidationError

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.generators.builtin import BUILTIN_SCENES, cornell_box
from workers.scene.geometry.compile import compile_scene
from workers.scene.portability.io import dump_scene, load_scene

YAML_SCENE = """\
name: teapotless
materials:
  grey: {type: diffuse, reflectance: [0.5, 0.5, 0.5]}
objects:
  - name: model
    shape: {type: mesh, path: meshes/ico.ply}
    material: grey
    instances:
      - {translate: [-2, 0, 0]}
      - {translate: [2, 0, 0], rotate: [0, 90, 0]}
lights:
  - {type: point, position: [0, 5, 0], intensity: [10, 10, 10]}
camera: {position: [0, 1, 8], target: [0, 0, 0]}
"""


def cornell_dict():
    return cornell_box().model_dump(mode="json")


def scene_error(source) -> SceneError:
    with pytest.raises(SceneError) as caught:
        load_scene(source)
    return caught.value


def test_builtin_names_dicts_and_specs_load():
    scene, base = load_scene("cornell_box")
    assert scene == cornell_box() and base is None
    assert load_scene(cornell_dict())[0] == scene
    assert load_scene(scene) == (scene, None)


def test_yaml_file_resolves_mesh_paths_against_its_folder(tmp_path):
    (tmp_path / "meshes").mkdir()
    trimesh.creation.icosphere(subdivisions=1).export(tmp_path / "meshes" / "ico.ply")
    (tmp_path / "scene.yaml").write_text(YAML_SCENE)
    scene, base = load_scene(str(tmp_path / "scene.yaml"))
    assert base == tmp_path.resolve()
    compiled = compile_scene(scene, base)
    assert compiled.num_triangles == 2 * 80
    assert compiled.bounds[0][0] == pytest.approx(-3.0) and compiled.bounds[1][0] == pytest.approx(3.0)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
@pytest.mark.parametrize("name", sorted(BUILTIN_SCENES))
def test_dump_and_load_round_trip(tmp_path, name, suffix):
    scene = BUILTIN_SCENES[name]()
    path = dump_scene(scene, tmp_path / f"scene{suffix}")
    assert load_scene(path)[0] == scene


def test_malformed_files_name_the_file_and_line(tmp_path):
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("name: x\nmaterials: {grey: [1, 2\nobjects: []\n")
    error = scene_error(bad_yaml)
    assert error.field == str(bad_yaml) and "malformed YAML at line" in error.problem
    bad_json = tmp_path / "bad.json"
    bad_json.write_text('{"name": "x",\n "materials": }')
    error = scene_error(bad_json)
    assert error.field == str(bad_json) and "malformed JSON at line 2" in error.problem
    listing = tmp_path / "list.yaml"
    listing.write_text("- 1\n- 2\n")
    assert "mapping" in scene_error(listing).problem
    assert "not found" in scene_error(tmp_path / "missing.yaml").problem


def test_unknown_builtin_lists_the_known_ones():
    error = scene_error("cornell_bx")
    assert error.field == "scene" and "unknown built-in scene 'cornell_bx'" in error.problem
    assert "cornell_box" in error.problem


def mutated(change):
    data = cornell_dict()
    change(data)
    return data


SPHERE = {"name": "ball", "shape": {"type": "sphere"}, "material": "white"}


@pytest.mark.parametrize(
    ("change", "field", "problem"),
    [
        (
            lambda d: d["objects"].insert(
                2, copy.deepcopy(SPHERE) | {"shape": {"type": "sphere", "radius": 0}}
            ),
            "objects[2].shape.radius",
            "greater than 0",
        ),
        (
            lambda d: d["objects"][1].update(material="chrome"),
            "objects[1].material",
            "unknown material 'chrome'",
        ),
        (lambda d: d["objects"][0].update(shape={"type": "mesh"}), "objects[0].shape.path", "Field required"),
        (
            lambda d: d["objects"][0].update(shape={"type": "procedural", "generator": 3}),
            "objects[0].shape.generator",
            "valid string",
        ),
        (
            lambda d: d.update(camera={"position": [0, 4, 0], "target": [0, 0, 0], "up": [0, 1, 0]}),
            "camera",
            "looks along its up vector",
        ),
        (
            lambda d: d.update(
                lights=[{"type": "point", "position": [0, float("nan"), 0], "intensity": [1, 1, 1]}]
            ),
            "lights[0].position[1]",
            "finite",
        ),
        (
            lambda d: d["materials"].update(white={"type": "diffuse", "reflectance": {"type": "image"}}),
            "materials.white.reflectance.path",
            "Field required",
        ),
        (
            lambda d: d["objects"][3].update(emission=[-1, 0, 0]),
            "objects[3].emission[0]",
            "greater than or equal",
        ),
        (lambda d: d.update(environment={"type": "envmap"}), "environment", "exactly one of"),
        (
            lambda d: d.update(environment={"builtin": "sunset"}),
            "environment",
            "no `type`: give one of 'envmap', 'constant'",
        ),
        (lambda d: d.update(environment={"type": "hdr"}), "environment", "type 'hdr' is none of 'envmap'"),
        (
            lambda d: d["objects"][0].update(shape={"radius": 1}),
            "objects[0].shape",
            "no `type`: give one of 'mesh', 'sphere'",
        ),
        (lambda d: d.update(objects=[]), "objects", "at least 1"),
        (lambda d: d.update(colour="red"), "colour", "Extra inputs"),
    ],
)
def test_validation_errors_become_scene_errors_on_dotted_fields(change, field, problem):
    error = scene_error(mutated(change))
    assert error.field == field
    assert problem in error.problem


def test_camera_along_up_is_a_validation_error_at_construction():
    with pytest.raises(ValidationError, match="up vector"):
        spec.Camera(position=(0, 0, 0), target=(0, -3, 0), up=(0, 1, 0))


def test_nan_in_a_json_file_is_reported(tmp_path):
    data = cornell_dict()
    data["objects"][0]["transform"]["translate"] = [0, float("nan"), 0]
    path = tmp_path / "nan.json"
    path.write_text(json.dumps(data))  # json writes NaN, which Python's reader accepts
    error = scene_error(path)
    assert error.field == "objects[0].transform.translate[1]" and "finite" in error.problem
    assert np.isnan(json.loads(path.read_text())["objects"][0]["transform"]["translate"][1])
