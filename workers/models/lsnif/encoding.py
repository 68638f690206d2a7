"""LSNIF's input encoder (Sec. 3.2): a sparse grid whose features live only around occupied voxels.

The grids of `workers.nn` place lattice vertices at x * (N - 1) + 0.5, so voxel faces do not fall on
lattice planes: a point on a face reads the corners of the lattice cell around it, and a ray that starts
on the surface starts inside an occupied voxel. The stored vertices are therefore those of every lattice
cell touching an occupied (closed) voxel: every point the encoder is asked about reads stored corners,
and empty space stores nothing. The vertex set is a pure function of the voxels, so an artifact stores
the voxels and the feature table, never the keys.

Levels with more vertices than the table size M fold their rows modulo M (shared rows, as a hash table
of size M shares them), which bounds memory at the paper's M = 2^17 per level.

A corner finds its row through a dense per-level map (vertex -> row, -1 where nothing is stored) rather
than the parent's binary search: training spent half its time in `searchsorted`, and the map (int32,
(N_l + 1)^3 entries, 8.6 MB at 128^3) is rebuilt from the keys on load, never stored.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from workers.nn.configs import HashGridConfig
from workers.nn.encodings.grid import GridGeometry, outer_combine, vertex_pairs
from workers.nn.encodings.grid_kernels import RowRule
from workers.nn.encodings.hashgrid import INIT_RANGE
from workers.nn.encodings.sparse_hashgrid import SparseHashGrid


def occupied_vertices(occupied: np.ndarray, geometry: GridGeometry) -> list[Tensor]:
    """Per level, the lattice vertices [M_l, 3] of cells touching occupied voxels of [0, 1]^3."""
    resolution = occupied.shape[0]
    voxels = np.argwhere(occupied)
    if len(voxels) == 0:  # an empty object still needs a (tiny) table to be a valid module
        voxels = np.zeros((1, 3), np.int64)
    levels = []
    for level in range(geometry.n_levels):
        scale = geometry.scale(level)
        first = np.floor(voxels / resolution * scale + 0.5).astype(np.int64)
        last = np.floor((voxels + 1) / resolution * scale + 0.5).astype(np.int64) + 1  # + the upper corner
        span = int((last - first).max()) + 1
        steps = np.stack(np.meshgrid(*[np.arange(span)] * 3, indexing="ij"), -1).reshape(-1, 3)
        candidates = first[:, None, :] + steps[None]
        keep = np.all(candidates <= last[:, None, :], axis=-1)
        vertices = np.unique(candidates[keep], axis=0)
        side = geometry.vertices_per_side(level)
        vertices = vertices[np.all((vertices >= 0) & (vertices < side), axis=1)]
        levels.append(torch.from_numpy(vertices))
    return levels


class VoxelGridEncoding(SparseHashGrid):
    """`SparseHashGrid` over the vertices of occupied voxels, on the lattice of `grid`, with at most the
    table size 2^log2_table_size rows per level."""

    def __init__(self, occupied: np.ndarray, grid: HashGridConfig) -> None:
        geometry = grid.geometry(3)
        super().__init__(
            occupied_vertices(occupied, geometry),
            3,
            grid.features_per_level,
            grid.base_resolution,
            grid.per_level_scale,
        )
        self.table_size = 1 << grid.log2_table_size
        sizes = [min(size, self.table_size) for _, size in self.level_blocks]
        self.level_blocks = [(sum(sizes[:level]), size) for level, size in enumerate(sizes)]
        self.table = nn.Parameter(
            torch.empty(sum(sizes), grid.features_per_level).uniform_(-INIT_RANGE, INIT_RANGE)
        )
        for level in range(grid.levels):
            keys = self.level_keys(level)
            row_map = torch.full((self.geometry.vertices_per_side(level) ** 3,), -1, dtype=torch.int32)
            row_map[keys] = torch.remainder(torch.arange(keys.numel()), sizes[level]).to(torch.int32)
            self.register_buffer(f"row_map_{level}", row_map, persistent=False)

    def kernel_lookups(self) -> tuple[RowRule, list[Tensor]]:
        return RowRule.ROW_MAP, [getattr(self, f"row_map_{level}") for level in range(self.geometry.n_levels)]

    def corner_rows(self, level: int, cell: Tensor) -> tuple[Tensor, Tensor]:
        side = self.geometry.vertices_per_side(level)
        strides = side ** torch.arange(3, device=cell.device)
        query = outer_combine(vertex_pairs(cell, strides), torch.add)
        rows = getattr(self, f"row_map_{level}")[query].long()
        stored = rows >= 0
        return rows.clamp_(min=0), stored
