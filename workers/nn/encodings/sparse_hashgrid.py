"""Sparse multiresolution grid (LSNIF Sec. 3.2): features only on a given set of lattice vertices.

LSNIF queries points that lie on occupied voxels' boundaries, so most vertices of a dense grid are never
read. This grid stores one feature row per listed vertex and finds it by binary search
(`torch.searchsorted`) over the sorted int64 linear keys of the vertices, so it has no hash collisions.
Corners that are not stored read zeros and receive no gradient.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from workers.nn.encodings.grid import (
    GridGeometry,
    cell_and_fraction,
    corner_offsets,
    interpolate_grid,
    outer_combine,
    vertex_pairs,
)
from workers.nn.encodings.grid_kernels import KernelIndexing, RowRule
from workers.nn.encodings.hashgrid import INIT_RANGE


def _linear_keys(vertices: Tensor, side: int) -> Tensor:
    """x-fastest linear index of vertices [M, d], the same layout as a dense `HashGrid` level."""
    strides = side ** torch.arange(vertices.shape[-1], device=vertices.device)
    return (vertices * strides).sum(-1)


def vertices_touched(geometry: GridGeometry, points: Tensor) -> list[Tensor]:
    """Per level, the distinct vertices [M_l, d] whose features interpolating `points` [N, d] reads.

    A model passes points that cover its input domain densely (e.g. samples of the occupied voxels'
    faces) to build the vertex sets of a `SparseHashGrid`.
    """
    offsets = corner_offsets(geometry.n_dims).to(points.device)
    touched = []
    for level in range(geometry.n_levels):
        cell, _ = cell_and_fraction(
            points.reshape(-1, geometry.n_dims).clamp(0.0, 1.0), geometry.scale(level)
        )
        touched.append(torch.unique((cell[:, None, :] + offsets).reshape(-1, geometry.n_dims), dim=0))
    return touched


class SparseHashGrid(nn.Module):
    """A grid with the level geometry of `HashGrid` that stores features only on `vertices[l]` [M_l, d]."""

    def __init__(
        self,
        vertices: Sequence[Tensor],
        n_input_dims: int = 3,
        n_features_per_level: int = 2,
        base_resolution: int = 16,
        per_level_scale: float = 2.0,
    ) -> None:
        super().__init__()
        self.geometry = GridGeometry(n_input_dims, len(vertices), base_resolution, per_level_scale)
        self.n_features_per_level = n_features_per_level
        sizes = []
        for level, level_vertices in enumerate(vertices):
            keys = self._validated_keys(level, level_vertices)
            self.register_buffer(f"keys_{level}", keys)
            sizes.append(keys.numel())
        self.level_blocks = [(sum(sizes[:level]), size) for level, size in enumerate(sizes)]
        self.table = nn.Parameter(
            torch.empty(sum(sizes), n_features_per_level).uniform_(-INIT_RANGE, INIT_RANGE)
        )

    def _validated_keys(self, level: int, vertices: Tensor) -> Tensor:
        side = self.geometry.vertices_per_side(level)
        vertices = torch.as_tensor(vertices, dtype=torch.int64).reshape(-1, self.geometry.n_dims)
        if vertices.numel() == 0:
            raise ValueError(f"level {level} has no stored vertices")
        if vertices.min() < 0 or vertices.max() >= side:
            raise ValueError(f"level {level} vertices must lie in [0, {side - 1}]^{self.geometry.n_dims}")
        return torch.unique(_linear_keys(vertices, side))

    @property
    def n_input_dims(self) -> int:
        return self.geometry.n_dims

    @property
    def n_output_dims(self) -> int:
        return self.geometry.n_levels * self.n_features_per_level

    def level_keys(self, level: int) -> Tensor:
        """Sorted linear keys of the stored vertices of `level`; row i of the level block stores key i."""
        return getattr(self, f"keys_{level}")

    def corner_rows(self, level: int, cell: Tensor) -> tuple[Tensor, Tensor]:
        """Rows [N, 2^d] within the level block and whether each corner is stored [N, 2^d]."""
        side = self.geometry.vertices_per_side(level)
        strides = side ** torch.arange(self.geometry.n_dims, device=cell.device)
        query = outer_combine(vertex_pairs(cell, strides), torch.add)
        keys = self.level_keys(level)
        rows = torch.searchsorted(keys, query.reshape(-1)).clamp_(max=keys.numel() - 1).view_as(query)
        return rows, keys[rows] == query

    def kernel_lookups(self) -> tuple[RowRule, list[Tensor]]:
        """The row rule of every level and its lookup tensor (here the sorted keys)."""
        return RowRule.SORTED_KEYS, [self.level_keys(level) for level in range(self.geometry.n_levels)]

    def kernel_indexing(self) -> KernelIndexing:
        """Flat arrays for the CPU kernels, rebuilt only when a lookup tensor changes (load_state_dict
        copies into the buffers in place, which bumps their version)."""
        rule, lookups = self.kernel_lookups()
        stamp = tuple((t.data_ptr(), t._version) for t in lookups)
        if getattr(self, "_kernel_stamp", None) != stamp:
            self._kernel_indexing = KernelIndexing.build(
                rules=[rule] * len(lookups),
                sizes=[size for _, size in self.level_blocks],
                lookups=[t.cpu().numpy() for t in lookups],
            )
            self._kernel_stamp = stamp
        return self._kernel_indexing

    def forward(self, x: Tensor) -> Tensor:
        """Encode x [..., d] in [0, 1]^d (clamped) into [..., n_levels * n_features_per_level]."""
        return interpolate_grid(x, self.table, self.geometry, self.level_blocks, self)
