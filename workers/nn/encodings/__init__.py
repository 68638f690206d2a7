"""Input encodings: dense and sparse hash grids, shared-input composite, SH, Fourier, IPE, one-blob."""

from workers.nn.encodings.composite import SharedInputsEncoding
from workers.nn.encodings.fourier import FourierFeatures, IntegratedPositionalEncoding, octave_frequencies
from workers.nn.encodings.grid import GridGeometry
from workers.nn.encodings.hashgrid import HashGrid
from workers.nn.encodings.hashgrid_reference import reference_hashgrid_encode
from workers.nn.encodings.one_blob import OneBlob
from workers.nn.encodings.sparse_hashgrid import SparseHashGrid, vertices_touched
from workers.nn.encodings.spherical_harmonics import SphericalHarmonics, spherical_harmonics

__all__ = [
    "FourierFeatures",
    "GridGeometry",
    "HashGrid",
    "IntegratedPositionalEncoding",
    "OneBlob",
    "SharedInputsEncoding",
    "SparseHashGrid",
    "SphericalHarmonics",
    "octave_frequencies",
    "reference_hashgrid_encode",
    "spherical_harmonics",
    "vertices_touched",
]
