"""Networks from small JSON-shaped parts, as tiny-cuda-nn builds them: each config says what to build and
`.build(n_input_dims, ...)` builds it, so every kind names its grid and MLP knobs the same way and a
network's description round-trips through JSON (job submissions, artifact manifests).

- `EncodingConfig` is a union discriminated by `type` over the encodings of `workers.nn.encodings` that
  map one tensor x [..., n_input_dims] to features [..., n_output_dims]: `hash_grid`,
  `spherical_harmonics`, `frequency`, `one_blob`, and `shared_inputs` (one encoding shared by several
  points, itself configured by an `EncodingConfig`).
- `HashTableConfig` is the part of a hash grid a user sets when the model derives the lattice (`lod`: one
  level per LoD octave from the coarsest LoD's resolution, scale 2); the model builds it on the lattice it
  derives with `build_on(geometry)`. `HashGridConfig` is a table plus its own lattice.
- `MLPConfig` is a fully connected network of `width` x `depth` hidden units.

Each is a `StrictModel`: a misspelt key is an error naming it.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field

from workers.nn.encodings.composite import SharedInputsEncoding
from workers.nn.encodings.fourier import FourierFeatures, octave_frequencies
from workers.nn.encodings.grid import GridGeometry
from workers.nn.encodings.hashgrid import HashGrid
from workers.nn.encodings.one_blob import OneBlob
from workers.nn.encodings.spherical_harmonics import MAX_DEGREE, SphericalHarmonics
from workers.nn.mlp import ACTIVATIONS, MLP
from workers.scene.format.strict import StrictModel

Activation = Literal[tuple(ACTIVATIONS)]  # the names `workers.nn.mlp.make_activation` knows


class HashTableConfig(StrictModel):
    """The feature table of a multiresolution hash grid (instant-ngp): F features per vertex and T = 2^k
    rows per level; levels with more vertices than T hash into it."""

    features_per_level: int = Field(2, ge=1, le=16, description="F: features per lattice vertex and level.")
    log2_table_size: int = Field(
        19, ge=8, le=24, description="log2 T: rows per level; finer levels hash into them."
    )

    def build_on(self, geometry: GridGeometry) -> HashGrid:
        """The hash grid of this table on a lattice the caller derives."""
        return HashGrid(
            n_input_dims=geometry.n_dims,
            n_levels=geometry.n_levels,
            n_features_per_level=self.features_per_level,
            log2_hashmap_size=self.log2_table_size,
            base_resolution=geometry.base_resolution,
            per_level_scale=geometry.per_level_scale,
        )

    def describe(self) -> str:
        return f"{self.features_per_level} features, table 2^{self.log2_table_size}"


class HashGridConfig(HashTableConfig):
    """A hash grid with its own lattice: L levels of resolution floor(N_min * b^l) (instant-ngp Eq. 2).
    The defaults are instant-ngp's."""

    type: Literal["hash_grid"] = Field("hash_grid", description="Names this encoding.")
    levels: int = Field(16, ge=1, le=32, description="L: grid levels.")
    base_resolution: int = Field(16, ge=2, le=1 << 16, description="N_min: resolution of the coarsest level.")
    per_level_scale: float = Field(
        2.0, ge=1.0, le=8.0, description="b: resolution growth from one level to the next."
    )

    def geometry(self, n_input_dims: int) -> GridGeometry:
        return GridGeometry(n_input_dims, self.levels, self.base_resolution, self.per_level_scale)

    def build(self, n_input_dims: int) -> HashGrid:
        return self.build_on(self.geometry(n_input_dims))

    def describe(self) -> str:
        return (
            f"hash grid of {self.levels} levels from {self.base_resolution} (x{self.per_level_scale:g}), "
            f"{super().describe()}"
        )


class SphericalHarmonicsConfig(StrictModel):
    """Real spherical harmonics of directions up to `degree`: (degree + 1)^2 features."""

    type: Literal["spherical_harmonics"] = Field("spherical_harmonics", description="Names this encoding.")
    degree: int = Field(
        4, ge=0, le=MAX_DEGREE, description="The highest degree: (degree + 1)^2 features (0: constant)."
    )

    def build(self, n_input_dims: int = 3) -> SphericalHarmonics:
        if n_input_dims != 3:
            raise ValueError(f"spherical harmonics encode 3D directions, not {n_input_dims}D inputs")
        return SphericalHarmonics(self.degree)


class FrequencyConfig(StrictModel):
    """NeRF's positional encoding: sin and cos of base * 2^k x_i for k < n_frequencies (and x itself)."""

    type: Literal["frequency"] = Field("frequency", description="Names this encoding.")
    n_frequencies: int = Field(6, ge=1, le=32, description="Octaves of sin and cos per coordinate.")
    base: float = Field(math.pi, gt=0, description="The lowest frequency.")
    include_input: bool = Field(True, description="Also pass the coordinates themselves.")

    def build(self, n_input_dims: int) -> FourierFeatures:
        return FourierFeatures(
            n_input_dims, octave_frequencies(self.n_frequencies, self.base), self.include_input
        )


class OneBlobConfig(StrictModel):
    """A soft one-hot of each coordinate in [0, 1] over `n_bins` bins (Müller et al. 2019)."""

    type: Literal["one_blob"] = Field("one_blob", description="Names this encoding.")
    n_bins: int = Field(32, ge=2, le=1024, description="Bins per coordinate.")

    def build(self, n_input_dims: int) -> OneBlob:
        return OneBlob(n_input_dims, self.n_bins)


class SharedInputsConfig(StrictModel):
    """One `encoding` shared by `n_inputs` points packed side by side (Weier et al. 2023, Sec. 4.3)."""

    type: Literal["shared_inputs"] = Field("shared_inputs", description="Names this encoding.")
    n_inputs: int = Field(2, ge=1, le=64, description="Points packed side by side in the input.")
    encoding: EncodingConfig = Field(description="The encoding every point goes through.")

    def build(self, n_input_dims: int) -> SharedInputsEncoding:
        if n_input_dims % self.n_inputs:
            raise ValueError(f"{n_input_dims} input dimensions do not split into {self.n_inputs} points")
        return SharedInputsEncoding(self.encoding.build(n_input_dims // self.n_inputs), self.n_inputs)


EncodingConfig = Annotated[
    HashGridConfig | SphericalHarmonicsConfig | FrequencyConfig | OneBlobConfig | SharedInputsConfig,
    Field(discriminator="type"),
]
"""Any input encoding, chosen by its `type`; `.build(n_input_dims)` returns a module with `n_output_dims`."""

SharedInputsConfig.model_rebuild()


class MLPConfig(StrictModel):
    """`depth` hidden layers of `width` units with `activation` (He-initialised), then a linear output
    layer and `output_activation`."""

    width: int = Field(64, ge=8, le=1024, description="Units per hidden layer.")
    depth: int = Field(2, ge=1, le=8, description="Hidden layers.")
    activation: Activation = Field("relu", description="The hidden layers' activation.")
    output_activation: Activation = Field("none", description="The output layer's activation.")

    def build(self, n_input_dims: int, n_output_dims: int) -> MLP:
        return MLP(
            n_input_dims,
            n_output_dims,
            width=self.width,
            depth=self.depth,
            activation=self.activation,
            output_activation=self.output_activation,
        )

    def describe(self) -> str:
        return f"MLP {self.depth}x{self.width} {self.activation}"
