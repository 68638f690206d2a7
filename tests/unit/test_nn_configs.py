"""Network configs: each builds the module it describes (output dims, parameter count), bad values are
validation errors naming the field, configs round-trip through JSON, and `type` picks the encoding."""

from __future__ import annotations

import math

import pytest
import torch
from pydantic import BaseModel, TypeAdapter, ValidationError
from torch import nn

from workers.nn.configs import (
    EncodingConfig,
    FrequencyConfig,
    HashGridConfig,
    HashTableConfig,
    MLPConfig,
    OneBlobConfig,
    SharedInputsConfig,
    SphericalHarmonicsConfig,
)
from workers.nn.encodings import FourierFeatures, HashGrid, OneBlob, SharedInputsEncoding, SphericalHarmonics
from workers.nn.encodings.grid import GridGeometry
from workers.nn.mlp import MLP

ENCODING = TypeAdapter(EncodingConfig)


def n_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def hash_grid_rows(n_dims: int, levels: int, base: int, scale: float, log2_table_size: int) -> int:
    """Rows of an instant-ngp table: per level (N_l + 1)^d vertices, at most 2^k (hashed beyond)."""
    return sum(
        min((math.floor(base * scale**level + 1e-6) + 1) ** n_dims, 2**log2_table_size)
        for level in range(levels)
    )


@pytest.mark.parametrize("n_dims", [2, 3])
def test_hash_grid_config_builds_its_grid(n_dims):
    config = HashGridConfig(
        levels=5, features_per_level=4, log2_table_size=12, base_resolution=4, per_level_scale=1.5
    )
    grid = config.build(n_dims)
    assert isinstance(grid, HashGrid) and grid.n_output_dims == 5 * 4
    assert n_parameters(grid) == 4 * hash_grid_rows(n_dims, 5, 4, 1.5, 12)
    assert grid(torch.rand(7, n_dims)).shape == (7, 20)
    assert grid.geometry == config.geometry(n_dims)


def test_a_hash_table_builds_on_a_lattice_its_model_derives():
    # lod's lattice: one level per octave from the coarsest LoD (8^3) to the finest (64^3), scale 2.
    table = HashTableConfig(features_per_level=2, log2_table_size=14)
    grid = table.build_on(GridGeometry(3, 4, 8, 2.0))
    assert grid.geometry == GridGeometry(3, 4, 8, 2.0) and grid.n_output_dims == 8
    assert n_parameters(grid) == 2 * hash_grid_rows(3, 4, 8, 2.0, 14)


def test_mlp_config_builds_its_network():
    config = MLPConfig(width=32, depth=3, activation="leaky_relu", output_activation="sigmoid")
    mlp = config.build(10, 4)
    assert isinstance(mlp, MLP)
    assert n_parameters(mlp) == (10 * 32 + 32) + 2 * (32 * 32 + 32) + (32 * 4 + 4)
    assert sum(isinstance(m, nn.LeakyReLU) for m in mlp.modules()) == 3
    out = mlp(torch.randn(5, 10))
    assert out.shape == (5, 4) and torch.all((out > 0) & (out < 1))


@pytest.mark.parametrize(
    ("config", "n_input_dims", "n_output_dims"),
    [
        (SphericalHarmonicsConfig(degree=3), 3, 16),
        (FrequencyConfig(n_frequencies=4), 2, 2 * (2 * 4 + 1)),
        (FrequencyConfig(n_frequencies=4, include_input=False), 3, 3 * 2 * 4),
        (OneBlobConfig(n_bins=8), 2, 16),
    ],
)
def test_parameter_free_encodings_build_with_their_output_dims(config, n_input_dims, n_output_dims):
    encoding = config.build(n_input_dims)
    assert encoding.n_output_dims == n_output_dims and n_parameters(encoding) == 0
    assert encoding(torch.rand(6, n_input_dims)).shape == (6, n_output_dims)


def test_frequencies_are_octaves_of_the_base():
    encoding = FrequencyConfig(n_frequencies=3, base=1.0).build(1)
    assert encoding.frequencies.tolist() == [1.0, 2.0, 4.0]


def test_shared_inputs_encode_every_point_with_one_encoding():
    inner = HashGridConfig(levels=3, features_per_level=2, log2_table_size=10, base_resolution=4)
    shared = SharedInputsConfig(n_inputs=2, encoding=inner).build(6)
    assert shared.n_output_dims == 2 * 3 * 2
    assert n_parameters(shared) == n_parameters(inner.build(3))  # one table, not two
    with pytest.raises(ValueError, match="do not split into 2 points"):
        SharedInputsConfig(n_inputs=2, encoding=inner).build(5)


def test_spherical_harmonics_refuse_inputs_that_are_not_directions():
    with pytest.raises(ValueError, match="3D directions"):
        SphericalHarmonicsConfig().build(2)


@pytest.mark.parametrize(
    ("data", "module_class"),
    [
        ({"type": "hash_grid", "levels": 2, "log2_table_size": 10}, HashGrid),
        ({"type": "spherical_harmonics", "degree": 2}, SphericalHarmonics),
        ({"type": "frequency", "n_frequencies": 3}, FourierFeatures),
        ({"type": "one_blob"}, OneBlob),
        (
            {"type": "shared_inputs", "encoding": {"type": "one_blob", "n_bins": 4}, "n_inputs": 3},
            SharedInputsEncoding,
        ),
    ],
)
def test_the_type_field_picks_the_encoding_a_dict_builds(data, module_class):
    encoding = ENCODING.validate_python(data).build(3)
    assert type(encoding) is module_class


@pytest.mark.parametrize(
    ("parse", "data", "location"),
    [
        (HashGridConfig.model_validate, {"levels": 0}, ("levels",)),
        (HashGridConfig.model_validate, {"log2_table_size": 30}, ("log2_table_size",)),
        (HashGridConfig.model_validate, {"per_level_scale": 0.5}, ("per_level_scale",)),
        (HashTableConfig.model_validate, {"features_per_level": 0}, ("features_per_level",)),
        (MLPConfig.model_validate, {"activation": "swishy"}, ("activation",)),
        (MLPConfig.model_validate, {"depth": 0}, ("depth",)),
        (MLPConfig.model_validate, {"widht": 64}, ("widht",)),  # misspelt: extra fields are forbidden
        (ENCODING.validate_python, {"type": "frequency", "n_frequencies": 0}, ("frequency", "n_frequencies")),
        (
            ENCODING.validate_python,
            {"type": "shared_inputs", "encoding": {"type": "one_blob", "n_bins": 1}},
            ("shared_inputs", "encoding", "one_blob", "n_bins"),
        ),
    ],
)
def test_a_bad_value_is_a_validation_error_naming_its_field(parse, data, location):
    with pytest.raises(ValidationError) as error:
        parse(data)
    assert [e["loc"] for e in error.value.errors()] == [location]


def test_an_unknown_encoding_type_names_the_known_ones():
    with pytest.raises(ValidationError, match="'hash_grid', 'spherical_harmonics', 'frequency'"):
        ENCODING.validate_python({"type": "octree"})


@pytest.mark.parametrize(
    "config",
    [
        HashGridConfig(levels=3, features_per_level=3, log2_table_size=11, per_level_scale=1.26),
        SphericalHarmonicsConfig(degree=8),
        FrequencyConfig(n_frequencies=10, base=0.5, include_input=False),
        OneBlobConfig(n_bins=16),
        SharedInputsConfig(n_inputs=4, encoding=FrequencyConfig(n_frequencies=2)),
    ],
)
def test_an_encoding_config_round_trips_through_json(config):
    assert ENCODING.validate_json(ENCODING.dump_json(config)) == config


@pytest.mark.parametrize(
    "config",
    [MLPConfig(width=96, depth=5, activation="silu", output_activation="exponential"), HashTableConfig()],
)
def test_network_configs_round_trip_through_json(config: BaseModel):
    assert type(config).model_validate_json(config.model_dump_json()) == config
