"""Shared core of the dense and sparse grid encodings: level geometry and d-linear interpolation.

Both grids store one feature vector per integer lattice vertex and interpolate the 2^d corners of the
cell holding a point. They differ only in how a corner becomes a table row, so the interpolation and
its backward live here once and take that mapping (a `CornerIndex`) as an argument. On the CPU the
fused kernels of `grid_kernels.py` do the work; elsewhere (CUDA) a PyTorch path does.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
from torch import Tensor
from torch.autograd.function import once_differentiable
from torch.nn import functional as F

from workers.nn.encodings import grid_kernels
from workers.nn.encodings.grid_kernels import GridArrays, KernelIndexing


class CornerIndex(Protocol):
    """How a grid maps the corners of a cell to rows of its table, in the two forms the paths need."""

    def corner_rows(self, level: int, cell: Tensor) -> tuple[Tensor, Tensor | None]:
        """(level, cell origins [N, d] int64) -> (rows [N, 2^d] int64 within the level's block of the
        table, stored-corner mask [N, 2^d] or None).

        Corners are ordered by `outer_combine`: bit i of the corner number, counted from the most
        significant of d bits, is the offset along dimension i.
        """
        ...

    def kernel_indexing(self) -> KernelIndexing:
        """The same mapping as flat arrays for the CPU kernels."""
        ...


@dataclass(frozen=True)
class GridGeometry:
    """Per-level lattice of a multiresolution grid over [0, 1]^d.

    Level l has resolution N_l = floor(base * per_level_scale^l) (instant-ngp Eq. 2). A point x maps to
    lattice position x * (N_l - 1) + 0.5, as in tiny-cuda-nn (the "-1" counts vertices rather than
    cells, the 0.5 offset keeps lattice lines off the cube faces), so vertex coordinates run over
    0..N_l and a level has exactly (N_l + 1)^d vertices. tiny-cuda-nn scales by the unfloored
    base * per_level_scale^l - 1; the two agree whenever that product is an integer.
    """

    n_dims: int
    n_levels: int
    base_resolution: int
    per_level_scale: float

    def __post_init__(self) -> None:
        if not 2 <= self.n_dims <= 4:
            raise ValueError(f"grid encodings support 2 to 4 input dimensions, got {self.n_dims}")
        if self.n_levels < 1 or self.base_resolution < 2 or self.per_level_scale < 1.0:
            raise ValueError("need n_levels >= 1, base_resolution >= 2 and per_level_scale >= 1")

    def resolution(self, level: int) -> int:
        # The epsilon keeps e.g. 16 * 2^(1/3)^3 from flooring to 31 through round-off.
        return math.floor(self.base_resolution * self.per_level_scale**level + 1e-6)

    def scale(self, level: int) -> float:
        return float(self.resolution(level) - 1)

    def vertices_per_side(self, level: int) -> int:
        return self.resolution(level) + 1


def outer_combine(pairs: Tensor, op: Callable[[Tensor, Tensor], Tensor]) -> Tensor:
    """Combine per-dimension pairs [N, d, 2] into all 2^d corners [N, 2^d]; dimension 0 is the slowest."""
    out = pairs[:, 0]
    for dim in range(1, pairs.shape[1]):
        out = op(out[:, :, None], pairs[:, dim, None, :]).flatten(1)
    return out


def vertex_pairs(cell: Tensor, per_dim_factor: Tensor) -> Tensor:
    """(c_i * k_i, (c_i + 1) * k_i) per dimension [N, d, 2] for cell origins [N, d] and factors k [d]."""
    scaled = cell * per_dim_factor
    return torch.stack((scaled, scaled + per_dim_factor), dim=-1)


def corner_offsets(n_dims: int) -> Tensor:
    """The 0/1 offsets [2^d, d] of the corners in `outer_combine` order."""
    bits = torch.arange(2**n_dims)[:, None] >> torch.arange(n_dims - 1, -1, -1)[None, :]
    return bits & 1


def cell_and_fraction(x: Tensor, scale: float) -> tuple[Tensor, Tensor]:
    """Cell origin (int64) and position inside the cell for points x in [0, 1]^d."""
    position = x * scale + 0.5
    floor = position.floor()
    return floor.long(), position - floor


def _linear_factors(fraction: Tensor) -> Tensor:
    return torch.stack((1 - fraction, fraction), dim=-1)


def _weight_gradients(fraction: Tensor) -> list[Tensor]:
    """d weight / d fraction_j [N, 2^d] for each j: the other dimensions' factors times -1 or +1."""
    factors = _linear_factors(fraction)
    slopes = []
    for dim in range(fraction.shape[1]):
        varied = factors.clone()
        varied[:, dim, 0], varied[:, dim, 1] = -1.0, 1.0
        slopes.append(outer_combine(varied, torch.mul))
    return slopes


def _level_rows_and_weights(
    x: Tensor, geometry: GridGeometry, level: int, index: CornerIndex, dtype: torch.dtype
) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
    cell, fraction = cell_and_fraction(x, geometry.scale(level))
    fraction = fraction.to(dtype)
    rows, stored = index.corner_rows(level, cell)
    weights = outer_combine(_linear_factors(fraction), torch.mul)
    if stored is not None:
        weights = weights * stored
    return rows, weights, fraction, stored


_CPU_KERNELS = ContextVar("grid_cpu_kernels", default=True)


@contextmanager
def pytorch_path_on_cpu() -> Iterator[None]:
    """Run the PyTorch path on the CPU too: the peer the kernels are tested and benchmarked against."""
    token = _CPU_KERNELS.set(False)
    try:
        yield
    finally:
        _CPU_KERNELS.reset(token)


def _uses_kernels(x: Tensor, table: Tensor) -> bool:
    return (
        _CPU_KERNELS.get()
        and x.device.type == "cpu"
        and x.dtype == table.dtype
        and x.dtype in (torch.float32, torch.float64)
    )


def _check_tiling(blocks: list[tuple[int, int]], n_rows: int) -> None:
    """The kernels' table gradient zeroes each level's block rather than the whole gradient up front, so
    the blocks must cover the table's rows exactly, in level order."""
    end = 0
    for start, size in blocks:
        if start != end:
            raise ValueError(
                f"level blocks must tile the table in order: a block starts at {start}, not {end}"
            )
        end += size
    if end != n_rows:
        raise ValueError(f"level blocks cover {end} rows of a table of {n_rows}")


def _grid_arrays(
    geometry: GridGeometry, blocks: list[tuple[int, int]], index: CornerIndex, table: Tensor
) -> GridArrays:
    """The grid as the CPU kernels read it (their one argument besides points, table and outputs)."""
    _check_tiling(blocks, table.shape[0])
    levels = range(geometry.n_levels)
    indexing = index.kernel_indexing()
    return GridArrays(
        starts=np.asarray([start for start, _ in blocks], dtype=np.int64),
        scales=np.asarray([geometry.scale(level) for level in levels], dtype=table.detach().numpy().dtype),
        sides=np.asarray([geometry.vertices_per_side(level) for level in levels], dtype=np.int64),
        primes=tuple(int(prime) for prime in indexing.primes[: geometry.n_dims]),
        features=tuple(range(table.shape[1])),
        rules=indexing.rules,
        sizes=indexing.sizes,
        lookup_starts=indexing.lookup_starts,
        lookup=indexing.lookup,
    )


@contextmanager
def _torch_threads_kept() -> Iterator[None]:
    """Keep torch's intra-op thread count across a kernel call. Numba's OpenMP pool and torch share one
    OpenMP runtime, and the pool, started by the process's first parallel kernel, sets the runtime's thread
    count to Numba's (once torch has read it): a `torch.set_num_threads(1)` made before was undone, and prt's
    network then ran on two threads, 172-221 against 138-141 CPU ms a 48^2 frame on the loaded 2-core
    machine (the "network is faster in some processes" prt12a saw)."""
    threads = torch.get_num_threads()
    try:
        yield
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


class _GridInterpolation(torch.autograd.Function):
    """Interpolates all levels. On the CPU the fused kernels of `grid_kernels` compute each point's
    rows, weights and sums in one pass. Elsewhere a fused weighted gather (`embedding_bag`) per level
    does, and the backward scatters with `index_add_` (int64 rows).

    Rows and weights are recomputed in the backward rather than saved: at 2^18 points and 16 levels they
    would hold ~400 MB, and recomputing them costs less than a third of the backward.
    """

    @staticmethod
    def forward(
        ctx,
        x: Tensor,
        table: Tensor,
        geometry: GridGeometry,
        blocks: list[tuple[int, int]],
        index: CornerIndex,
    ) -> Tensor:
        n_points, n_features = x.shape[0], table.shape[1]
        ctx.save_for_backward(x, table)
        ctx.geometry, ctx.blocks, ctx.index = geometry, blocks, index
        if _uses_kernels(x, table):
            out = table.new_empty(n_points, geometry.n_levels * n_features)  # the kernel writes every entry
            grid = _grid_arrays(geometry, blocks, index, table)
            with _torch_threads_kept():
                grid_kernels.grid_forward(x.detach().numpy(), table.detach().numpy(), grid, out.numpy())
            return out
        out = table.new_empty(n_points, geometry.n_levels, n_features)
        for level, (start, size) in enumerate(blocks):
            rows, weights, _, _ = _level_rows_and_weights(x, geometry, level, index, table.dtype)
            out[:, level] = F.embedding_bag(
                rows, table.narrow(0, start, size), per_sample_weights=weights, mode="sum"
            )
        return out.flatten(1)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out: Tensor) -> tuple[Tensor | None, Tensor | None, None, None, None]:
        x, table = ctx.saved_tensors
        if _uses_kernels(x, table):
            # The kernel writes every entry of the gradients it is given; an empty one is not wanted.
            grad_x = x.new_empty(x.shape if ctx.needs_input_grad[0] else (0, x.shape[1]))
            grad_table = table.new_empty(table.shape if ctx.needs_input_grad[1] else (0, table.shape[1]))
            grid = _grid_arrays(ctx.geometry, ctx.blocks, ctx.index, table)
            with _torch_threads_kept():
                grid_kernels.grid_backward(
                    x.detach().numpy(),
                    table.detach().numpy(),
                    grad_out.to(table.dtype).contiguous().numpy(),
                    grid,
                    grad_table.numpy(),
                    grad_x.numpy(),
                )
            return (
                grad_x if ctx.needs_input_grad[0] else None,
                grad_table if ctx.needs_input_grad[1] else None,
                None,
                None,
                None,
            )
        grad_x = torch.zeros_like(x) if ctx.needs_input_grad[0] else None
        grad_table = torch.zeros_like(table) if ctx.needs_input_grad[1] else None
        _backward_torch(ctx, x, table, grad_out, grad_x, grad_table)
        return grad_x, grad_table, None, None, None


def _backward_torch(
    ctx, x: Tensor, table: Tensor, grad_out: Tensor, grad_x: Tensor | None, grad_table: Tensor | None
) -> None:
    geometry: GridGeometry = ctx.geometry
    n_points, n_features = x.shape[0], table.shape[1]
    grad_out = grad_out.reshape(n_points, geometry.n_levels, n_features)
    for level, (start, size) in enumerate(ctx.blocks):
        rows, weights, fraction, stored = _level_rows_and_weights(x, geometry, level, ctx.index, table.dtype)
        grad_level = grad_out[:, level]
        if grad_table is not None:
            contributions = weights[..., None] * grad_level[:, None, :]
            grad_table.narrow(0, start, size).index_add_(0, rows.view(-1), contributions.view(-1, n_features))
        if grad_x is not None:
            level_table = table.narrow(0, start, size)
            for dim, slope in enumerate(_weight_gradients(fraction)):
                if stored is not None:
                    slope = slope * stored
                along = F.embedding_bag(rows, level_table, per_sample_weights=slope, mode="sum")
                grad_x[:, dim] += ((along * grad_level).sum(-1) * geometry.scale(level)).to(x.dtype)


def interpolate_grid(
    x: Tensor, table: Tensor, geometry: GridGeometry, blocks: list[tuple[int, int]], index: CornerIndex
) -> Tensor:
    """Encode points x [..., d] (clamped to [0, 1]^d) into [..., n_levels * n_features], level-major.

    `blocks[l]` is (first row, row count) of level l in `table`. Points outside the unit cube are
    clamped, so they read the boundary value and get zero gradient along the clamped dimensions.
    """
    if x.shape[-1] != geometry.n_dims:
        raise ValueError(f"expected inputs with {geometry.n_dims} coordinates, got shape {tuple(x.shape)}")
    flat = x.reshape(-1, geometry.n_dims).clamp(0.0, 1.0).contiguous()
    out = _GridInterpolation.apply(flat, table, geometry, blocks, index)
    return out.view(*x.shape[:-1], out.shape[-1])
