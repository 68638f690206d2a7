"""A kind config's nested parts: a part given as a dict (preset, override or constructor) updates the
kind's default for that field instead of replacing it with the part's class defaults."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from workers.nn.configs import EncodingConfig, HashGridConfig, OneBlobConfig
from workers.runtime.contract import resolve_preset
from workers.runtime.kind_config import TrainedKindConfig
from workers.runtime.training import Schedule, TrainConfig

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
