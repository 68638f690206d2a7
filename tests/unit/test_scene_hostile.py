"""Scene files written by an attacker: refused while parsing, before anything is built, naming the file."""

import json
import time
from pathlib import Path

import pytest

from tests.support.hostile_inputs import YAML_ALIAS_BOMB
from workers.scene.format.errors import SceneError
from workers.scene.portability.io import (
    MAX_SCENE_DEPTH,
    MAX_SCENE_FILE_BYTES,
    MAX_SCENE_VALUES,
    load_scene,
    scene_from_dict,
)


def refusal(tmp_path, name: str, text: str) -> SceneError:
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(SceneError) as caught:
        load_scene(path)
    assert caught.value.field == str(path)
    return caught.value


def test_alias_bomb_is_refused_while_parsing(tmp_path):
    started = time.process_time()
    error = refusal(tmp_path, "scene.yaml", YAML_ALIAS_BOMB)
    assert f"more than {MAX_SCENE_VALUES} values" in error.problem
    # building the 10^8 leaves takes many seconds; refusing takes milliseconds (a relative bound)
    assert time.process_time() - started < 1.0


def test_a_few_shared_aliases_still_load(tmp_path):
    text = YAML_ALIAS_BOMB.split("      params:")[0] + "      params: {size: 4.0}\n"
    text += "lights: [&l {type: point, position: [0, 5, 0], intensity: [1, 1, 1]}, *l]\n"
    scene, _ = load_scene(_write(tmp_path, "scene.yaml", text))
    assert len(scene.lights) == 2


def test_self_referencing_alias_is_refused(tmp_path):
    error = refusal(tmp_path, "scene.yaml", "materials: &m {x: *m}\n")
    assert "contains it" in error.problem


@pytest.mark.parametrize("depth", [MAX_SCENE_DEPTH + 1, 100_000])
def test_deep_yaml_is_refused(tmp_path, depth):
    error = refusal(tmp_path, "scene.yaml", "materials: " + "[" * depth + "]" * depth + "\n")
    assert f"more than {MAX_SCENE_DEPTH} levels" in error.problem


@pytest.mark.parametrize("depth", [MAX_SCENE_DEPTH + 1, 100_000])
def test_deep_json_is_refused(tmp_path, depth):
    error = refusal(tmp_path, "scene.json", '{"materials": ' + "[" * depth + "]" * depth + "}")
    assert f"more than {MAX_SCENE_DEPTH} levels" in error.problem


def test_deep_dict_is_refused_naming_the_scene():
    data = json.loads(
        '{"materials": {}, "objects": [{"name": "x", "shape": {"type": "procedural", '
        '"generator": "ground_plane", "params": {"a": ' + "[" * 200 + "]" * 200 + "}}}]}"
    )
    with pytest.raises(SceneError) as caught:
        scene_from_dict(data)
    assert caught.value.field == "scene"


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize("suffix", ["yaml", "json"])
def test_a_plain_list_over_the_value_limit_is_refused_without_blaming_aliases(tmp_path, suffix):
    ones = ", ".join(["1"] * (MAX_SCENE_VALUES + 1))
    error = refusal(tmp_path, f"scene.{suffix}", f'{{"objects": [{ones}]}}')
    assert f"more than {MAX_SCENE_VALUES} values" in error.problem and "alias" not in error.problem


def test_a_scene_file_over_the_byte_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    path = tmp_path / "scene.yaml"
    path.write_text("objects: []\n" + "#" * MAX_SCENE_FILE_BYTES)
    monkeypatch.setattr(Path, "read_text", lambda *_, **__: pytest.fail("the file was read"))
    with pytest.raises(SceneError, match=f"over the limit of {MAX_SCENE_FILE_BYTES:,} bytes"):
        load_scene(path)
