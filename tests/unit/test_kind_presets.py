"""Every kind's presets are YAML files beside its config that validate against it, a bad one fails naming
its file and field, and every field of every config says what it does, its links to the measurements
behind a default landing on an entry of docs/results/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.unit.test_kind_config import config_tree
from workers.models.registry import get_kind, kind_names
from workers.models.render.config import RenderConfig
from workers.runtime.contract import PRESET_NAMES
from workers.runtime.presets import PresetError, load_preset, load_presets

ROOT = Path(__file__).resolve().parents[2]
RESULTS_LINK = re.compile(r"\]\(\.\./\.\./docs/results/(?P<page>[\w-]+\.md)#(?P<anchor>[\w-]+)\)")


def presets_folder(name: str) -> Path:
    return ROOT / "workers" / "models" / name / "presets"


@pytest.mark.parametrize("name", kind_names())
def test_a_kinds_presets_are_its_yaml_files(name):
    kind = get_kind(name)
    assert sorted(path.stem for path in presets_folder(name).glob("*.yaml")) == sorted(PRESET_NAMES)
    assert kind.presets == load_presets(kind.config_model, presets_folder(name))
    for preset in PRESET_NAMES:
        kind.resolve_config(preset, {})


def test_a_misspelt_field_fails_naming_the_file_and_the_field(tmp_path):
    path = tmp_path / "quick.yaml"
    path.write_text("width: 64\nsppp: 16\n")
    with pytest.raises(PresetError, match=r"quick\.yaml(.|\n)*sppp"):
        load_preset(RenderConfig, path)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("spp: '16'\n", "spp"),  # strict, as a submission: a quoted count is a mistake
        ("spp: 0\n", "spp"),
        ("train: {steps: 10}\n", "train"),  # render does not train
    ],
)
def test_a_value_that_does_not_fit_fails_naming_the_field(tmp_path, text, field):
    path = tmp_path / "default.yaml"
    path.write_text(text)
    with pytest.raises(PresetError, match=rf"default\.yaml(.|\n)*{field}"):
        load_preset(RenderConfig, path)


@pytest.mark.parametrize("text", ["- width\n- 64\n", "width: [64\n"])
def test_a_file_that_is_not_a_mapping_fails_naming_it(tmp_path, text):
    path = tmp_path / "paper.yaml"
    path.write_text(text)
    with pytest.raises(PresetError, match=r"paper\.yaml"):
        load_preset(RenderConfig, path)


def test_an_empty_file_sets_nothing(tmp_path):
    path = tmp_path / "default.yaml"
    path.write_text("# the config's defaults\n")
    assert load_preset(RenderConfig, path) == {}


def test_every_field_of_every_kinds_config_is_described():
    undescribed = [
        f"{model.__qualname__}.{field_name}"
        for name in kind_names()
        for model in config_tree(get_kind(name).config_model)
        for field_name, field in model.model_fields.items()
        if not field.description
    ]
    assert not undescribed, f"fields without a description: {sorted(set(undescribed))}"


def test_every_link_to_a_measurement_lands_on_an_entry():
    links = [
        (name, match["page"], match["anchor"])
        for name in kind_names()
        for model in config_tree(get_kind(name).config_model)
        for field in model.model_fields.values()
        for match in RESULTS_LINK.finditer(field.description or "")
    ]
    assert {page for _, page, _ in links} >= {"prt.md", "explore.md"}
    missing = [
        f"{name}: {page}#{anchor}"
        for name, page, anchor in links
        if f'<a id="{anchor}"></a>' not in (ROOT / "docs" / "results" / page).read_text()
    ]
    assert not missing, f"links to no entry: {missing}"
