"""A kind config's nested parts: a part given as a dict (preset, override or constructor) updates the
kind's default for that field instead of replacing it with the part's class defaults; and every model in
every registered kind's config refuses a key it does not declare."""

from __future__ import annotations

import typing
from collections.abc import Callable, Iterator
from functools import partial

import pytest
from pydantic import BaseModel, ValidationError

from workers.models.registry import get_kind, kind_names
from workers.nn.configs import EncodingConfig, HashGridConfig, MLPConfig, OneBlobConfig
from workers.runtime.contract import resolve_preset
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import OptimizerConfig, Schedule, TrainConfig

KIND_GRID = HashGridConfig(levels=2, features_per_level=3, log2_table_size=17, base_resolution=64)


class ToyConfig(TrainedKindConfig):
    grid: HashGridConfig = KIND_GRID
    encoding: EncodingConfig = KIND_GRID
    train: TrainConfig = TrainConfig(steps=500, schedule=Schedule(lr=0.01))


def test_a_partial_part_keeps_the_kinds_other_values():
    config = ToyConfig(grid={"log2_table_size": 12}, train={"steps": 5, "schedule": {"warmup_steps": 2}})
    assert config.grid == KIND_GRID.model_copy(update={"log2_table_size": 12})
    assert (config.train.steps, config.train.schedule.lr, config.train.schedule.warmup_steps) == (5, 0.01, 2)


def test_a_part_of_another_type_replaces_the_default():
    assert ToyConfig(encoding={"type": "one_blob"}).encoding == OneBlobConfig()
    assert ToyConfig(encoding={"levels": 3}).encoding == KIND_GRID.model_copy(update={"levels": 3})


def test_presets_and_overrides_update_the_kinds_default_parts():
    presets = {"quick": {"grid": {"base_resolution": 32}}, "default": {}, "paper": {}}
    config = resolve_preset(ToyConfig, presets, "quick", {"grid": {"levels": 4}})
    assert config.grid == KIND_GRID.model_copy(update={"base_resolution": 32, "levels": 4})


def test_a_misspelt_key_in_a_part_is_an_error_naming_it():
    with pytest.raises(ValidationError) as error:
        ToyConfig(grid={"levles": 3})
    assert [e["loc"] for e in error.value.errors()] == [("grid", "levles")]


def models_in(annotation) -> Iterator[type[BaseModel]]:
    """The models an annotation names, through Optional, unions, Annotated, list, tuple and dict."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
    for argument in typing.get_args(annotation):
        yield from models_in(argument)


def config_tree(model: type[BaseModel]) -> set[type[BaseModel]]:
    """`model` and every model reachable through its fields' types."""
    found, pending = set(), [model]
    while pending:
        current = pending.pop()
        if current not in found:
            found.add(current)
            pending.extend(m for field in current.model_fields.values() for m in models_in(field.annotation))
    return found


def refused_keys(validate: Callable[[], object]) -> list[tuple]:
    """Where `validate()` met a key its model does not declare (whatever else is wrong with its input)."""
    try:
        validate()
    except ValidationError as error:
        return [e["loc"] for e in error.errors() if e["type"] == "extra_forbidden"]
    return []


def test_every_model_in_every_kinds_config_refuses_an_unknown_key():
    trees = {name: config_tree(get_kind(name).config_model) for name in kind_names()}
    reached = set().union(*trees.values())
    # the walk reaches the nested parts, the dict-valued `optimizers`' included
    assert {TrainConfig, OptimizerConfig, Schedule, MLPConfig} <= reached
    for name, tree in trees.items():
        for model in tree:
            assert refused_keys(partial(model.model_validate, {"misspelt_key": 1})) == [("misspelt_key",)], (
                f"{name}: {model.__module__}.{model.__qualname__} accepts unknown keys"
            )


@pytest.mark.parametrize(
    ("overrides", "path"),
    [
        ({"train": {"stpes": 10}}, ("train", "stpes")),
        ({"train": {"schedule": {"lrr": 0.1}}}, ("train", "schedule", "lrr")),
    ],
)
def test_a_misspelt_training_key_in_an_override_is_an_error_at_its_path(overrides, path):
    trained = [name for name in kind_names() if "train" in get_kind(name).config_model.model_fields]
    assert trained
    for name in trained:
        assert refused_keys(partial(get_kind(name).resolve_config, "quick", overrides)) == [path], name
