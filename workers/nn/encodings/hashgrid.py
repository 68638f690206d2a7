"""Multiresolution hash-grid encoding (Müller et al. 2022, instant-ngp) with a fast CPU backward."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from workers.nn.encodings.grid import GridGeometry, interpolate_grid, outer_combine, vertex_pairs
from workers.nn.encodings.grid_kernels import KernelIndexing, RowRule

HASH_PRIMES = (1, 2654435761, 805459861, 3674653429)
"""The spatial-hash primes of instant-ngp, one per input dimension."""

INIT_RANGE = 1e-4


class HashGrid(nn.Module):
    """instant-ngp hash grid: levels whose (N_l + 1)^d vertices fit the table are indexed densely,
    finer levels hash vertex coordinates with XOR-combined prime products, masked to the table size.

    All levels live in one flat parameter `table` [rows, n_features_per_level] so the backward is a
    single `index_add_` target; `level_blocks[l]` is (first row, row count) of level l. Lattice geometry
    (resolutions, the 0.5 offset) is described in `GridGeometry`.
    """

    def __init__(
        self,
        n_input_dims: int = 3,
        n_levels: int = 16,
        n_features_per_level: int = 2,
        log2_hashmap_size: int = 19,
        base_resolution: int = 16,
        per_level_scale: float = 2.0,
    ) -> None:
        super().__init__()
        if not 1 <= log2_hashmap_size <= 32:
            raise ValueError(f"log2_hashmap_size must be in 1..32, got {log2_hashmap_size}")
        self.geometry = GridGeometry(n_input_dims, n_levels, base_resolution, per_level_scale)
        self.n_features_per_level = n_features_per_level
        self.hashmap_size = 2**log2_hashmap_size
        sizes = [self._level_size(level) for level in range(n_levels)]
        self.level_blocks = [(sum(sizes[:level]), size) for level, size in enumerate(sizes)]
        self.table = nn.Parameter(
            torch.empty(sum(sizes), n_features_per_level).uniform_(-INIT_RANGE, INIT_RANGE)
        )

    @property
    def n_input_dims(self) -> int:
        return self.geometry.n_dims

    @property
    def n_output_dims(self) -> int:
        return self.geometry.n_levels * self.n_features_per_level

    def is_hashed(self, level: int) -> bool:
        return self.geometry.vertices_per_side(level) ** self.geometry.n_dims > self.hashmap_size

    def _level_size(self, level: int) -> int:
        return (
            self.hashmap_size
            if self.is_hashed(level)
            else self.geometry.vertices_per_side(level) ** self.geometry.n_dims
        )

    def corner_rows(self, level: int, cell: Tensor) -> tuple[Tensor, None]:
        """Rows [N, 2^d], within the level's block, of the corners of cells with origins `cell` [N, d]."""
        n_dims = self.geometry.n_dims
        if self.is_hashed(level):
            primes = torch.tensor(HASH_PRIMES[:n_dims], device=cell.device)
            hashes = outer_combine(vertex_pairs(cell, primes), torch.bitwise_xor)
            return hashes.bitwise_and_(self.hashmap_size - 1), None
        side = self.geometry.vertices_per_side(level)
        strides = side ** torch.arange(n_dims, device=cell.device)
        return outer_combine(vertex_pairs(cell, strides), torch.add), None

    def kernel_indexing(self) -> KernelIndexing:
        levels = range(self.geometry.n_levels)
        return KernelIndexing.build(
            rules=[RowRule.HASHED if self.is_hashed(level) else RowRule.LINEAR for level in levels],
            sizes=[size for _, size in self.level_blocks],
            lookups=[None for _ in levels],
            primes=HASH_PRIMES[: self.geometry.n_dims],
        )

    def forward(self, x: Tensor) -> Tensor:
        """Encode x [..., d] in [0, 1]^d (clamped) into [..., n_levels * n_features_per_level]."""
        return interpolate_grid(x, self.table, self.geometry, self.level_blocks, self)
