"""A straightforward hash-grid encoding: loops over levels and corners, plain indexing, autograd backward.

It recomputes the indexing formula corner by corner from `HashGrid`'s configuration alone, so tests can
compare the fast path against it and the benchmark can report the fast path's speed-up.
"""

from __future__ import annotations

import itertools

import torch
from torch import Tensor

from workers.nn.encodings.hashgrid import HASH_PRIMES, HashGrid


def reference_hash_index(grid: HashGrid, level: int, vertex: Tensor) -> Tensor:
    """Table row of integer vertices [N, d] on `level`, written out per dimension."""
    n_dims = grid.geometry.n_dims
    if grid.is_hashed(level):
        index = torch.zeros_like(vertex[:, 0])
        for dim in range(n_dims):
            index = index ^ (vertex[:, dim] * HASH_PRIMES[dim])
        index = index % grid.hashmap_size
    else:
        side = grid.geometry.vertices_per_side(level)
        index = sum(vertex[:, dim] * side**dim for dim in range(n_dims))
    return index + grid.level_blocks[level][0]


def reference_hashgrid_encode(grid: HashGrid, x: Tensor) -> Tensor:
    """Same result as `grid(x)` for x [N, d]."""
    x = x.clamp(0.0, 1.0)
    levels = []
    for level in range(grid.geometry.n_levels):
        position = x * grid.geometry.scale(level) + 0.5
        cell = position.floor()
        fraction = position - cell
        encoded = 0.0
        for offset in itertools.product((0, 1), repeat=grid.geometry.n_dims):
            weight = torch.ones_like(x[:, 0])
            for dim, o in enumerate(offset):
                weight = weight * (fraction[:, dim] if o else 1 - fraction[:, dim])
            vertex = cell.long() + torch.tensor(offset, device=x.device)
            encoded = encoded + weight[:, None] * grid.table[reference_hash_index(grid, level, vertex)]
        levels.append(encoded)
    return torch.cat(levels, dim=-1)
