"""Hash-grid encoding: indexing formula, interpolation, fast backward against the reference, gradchecks."""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
from pathlib import Path

import numba
import pytest
import torch

from workers.nn.encodings.grid import GridGeometry, corner_offsets, interpolate_grid, pytorch_path_on_cpu
from workers.nn.encodings.hashgrid import HASH_PRIMES, HashGrid
from workers.nn.encodings.hashgrid_reference import reference_hashgrid_encode


def small_grid(n_dims: int, dtype=torch.float64) -> HashGrid:
    """Resolutions 2, 4, 8, 16 with a table that makes levels 0-1 dense and 2-3 hashed."""
    torch.manual_seed(n_dims)
    log2_size = {2: 6, 3: 8, 4: 11}[n_dims]
    grid = HashGrid(
        n_dims, n_levels=4, n_features_per_level=2, log2_hashmap_size=log2_size, base_resolution=2
    )
    grid.table.data.uniform_(-1, 1)  # larger than the 1e-4 init so differences are visible
    return grid.to(dtype)


def python_rows(grid: HashGrid, level: int, point: list[float]) -> list[tuple[int, float]]:
    """(table row, weight) of each corner, in exact Python integer and float arithmetic."""
    scale = grid.geometry.scale(level)
    side = grid.geometry.vertices_per_side(level)
    position = [p * scale + 0.5 for p in point]
    cell = [math.floor(p) for p in position]
    out = []
    for offset in itertools.product((0, 1), repeat=len(point)):
        vertex = [c + o for c, o in zip(cell, offset, strict=True)]
        if side ** len(point) <= grid.hashmap_size:
            row = sum(v * side**i for i, v in enumerate(vertex))
        else:
            h = 0
            for v, prime in zip(vertex, HASH_PRIMES, strict=False):
                h ^= v * prime
            row = h % grid.hashmap_size
        weight = math.prod(
            p - c if o else 1 - (p - c) for p, c, o in zip(position, cell, offset, strict=True)
        )
        out.append((row + grid.level_blocks[level][0], weight))
    return out


def test_level_resolutions_follow_floor_of_geometric_series():
    geometry = GridGeometry(3, n_levels=16, base_resolution=16, per_level_scale=1.3819)
    expected = [math.floor(16 * 1.3819**level) for level in range(16)]
    assert [geometry.resolution(level) for level in range(16)] == expected
    doubling = GridGeometry(3, n_levels=4, base_resolution=16, per_level_scale=2 ** (1 / 3))
    assert doubling.resolution(3) == 32  # exact powers survive round-off


def test_dense_levels_are_exactly_those_whose_vertices_fit_the_table():
    grid = HashGrid(3, n_levels=6, log2_hashmap_size=12, base_resolution=4, per_level_scale=2.0)
    for level, (_, size) in enumerate(grid.level_blocks):
        vertices = (grid.geometry.resolution(level) + 1) ** 3
        assert grid.is_hashed(level) == (vertices > 2**12)
        assert size == (2**12 if grid.is_hashed(level) else vertices)


@pytest.mark.parametrize("n_dims", [2, 3, 4])
def test_rows_and_weights_equal_exact_python_formula(n_dims):
    grid = small_grid(n_dims)
    points = torch.rand(16, n_dims, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    offsets = corner_offsets(n_dims)
    for level, (start, _) in enumerate(grid.level_blocks):
        cell = (points * grid.geometry.scale(level) + 0.5).floor().long()
        rows, _ = grid.corner_rows(level, cell)
        for p, point in enumerate(points.tolist()):
            expected = python_rows(grid, level, point)
            assert (rows[p] + start).tolist() == [row for row, _ in expected]
            assert (cell[p] + offsets).min() >= 0
        assert grid.is_hashed(level) == (level >= 2)


def test_hash_matches_uint32_formula_for_large_coordinates():
    grid = HashGrid(4, n_levels=1, log2_hashmap_size=19, base_resolution=2**20)
    cell = torch.tensor([[2**20 - 1, 123457, 2**19 + 3, 77]])
    rows, _ = grid.corner_rows(0, cell)
    for corner, offset in enumerate(corner_offsets(4).tolist()):
        h = 0
        for c, o, prime in zip(cell[0].tolist(), offset, HASH_PRIMES, strict=True):
            h ^= ((c + o) * prime) & 0xFFFFFFFF
        assert rows[0, corner].item() == h % 2**19


@pytest.mark.parametrize("n_dims", [2, 3, 4])
def test_interpolation_weights_sum_to_one(n_dims):
    grid = small_grid(n_dims)
    grid.table.data.fill_(1.0)
    points = torch.rand(64, n_dims, dtype=torch.float64)
    assert torch.allclose(grid(points), torch.ones(64, grid.n_output_dims, dtype=torch.float64))


@pytest.mark.parametrize("n_dims", [2, 3, 4])
def test_forward_equals_reference(n_dims):
    grid = small_grid(n_dims)
    points = torch.rand(200, n_dims, dtype=torch.float64)
    points[:4] = torch.tensor([0.0, 1.0, 0.5, 1.0 - 1e-12])[:, None]  # cube faces and corners
    assert torch.allclose(grid(points), reference_hashgrid_encode(grid, points), atol=1e-12)


@pytest.mark.parametrize("n_dims", [2, 3, 4])
def test_fast_backward_equals_reference_backward(n_dims):
    grid = small_grid(n_dims)
    points = torch.rand(300, n_dims, dtype=torch.float64, requires_grad=True)
    upstream = torch.randn(300, grid.n_output_dims, dtype=torch.float64)
    fast = torch.autograd.grad((grid(points) * upstream).sum(), (grid.table, points))
    slow = torch.autograd.grad(
        (reference_hashgrid_encode(grid, points) * upstream).sum(), (grid.table, points)
    )
    for a, b in zip(fast, slow, strict=True):
        assert torch.allclose(a, b, atol=1e-10)


def test_gradients_land_on_the_interpolated_entries_only():
    grid = small_grid(3)
    points = torch.tensor([[0.13, 0.71, 0.42], [0.9, 0.05, 0.66]], dtype=torch.float64)
    grid(points)[:, :].sum().backward()
    expected = torch.zeros(grid.table.shape[0], dtype=torch.float64)
    for level in range(grid.geometry.n_levels):
        for point in points.tolist():
            for row, weight in python_rows(grid, level, point):
                expected[row] += weight
    assert torch.allclose(grid.table.grad, expected[:, None].expand_as(grid.table.grad), atol=1e-12)
    touched = expected != 0
    assert touched.sum() > 0 and torch.all(grid.table.grad[~touched] == 0)


def test_float32_default_and_values_near_reference():
    grid = HashGrid(3, n_levels=8, log2_hashmap_size=14)
    assert grid.table.dtype == torch.float32
    assert grid.table.abs().max() <= 1e-4
    points = torch.rand(1000, 3)
    assert torch.allclose(grid(points), reference_hashgrid_encode(grid, points), atol=1e-9)


@pytest.mark.parametrize("n_dims", [2, 3])
def test_gradcheck_table_and_inputs_dense_and_hashed_levels(n_dims):
    grid = small_grid(n_dims)
    # Points away from cell boundaries, so finite differences stay inside one cell at every level.
    points = torch.tensor([[0.31, 0.47, 0.83], [0.62, 0.12, 0.27]], dtype=torch.float64)[:, :n_dims]

    def encode(x: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
        return interpolate_grid(x, table, grid.geometry, grid.level_blocks, grid)

    assert torch.autograd.gradcheck(encode, (points.requires_grad_(), grid.table))


def test_inputs_are_clamped_to_unit_cube_with_zero_gradient_outside():
    grid = small_grid(2)
    outside = torch.tensor([[-0.5, 1.7]], dtype=torch.float64, requires_grad=True)
    grid(outside).sum().backward()
    assert torch.allclose(grid(outside), grid(torch.tensor([[0.0, 1.0]], dtype=torch.float64)))
    assert torch.all(outside.grad == 0)


def test_leading_batch_dimensions_are_kept():
    grid = small_grid(3)
    assert grid(torch.rand(4, 5, 3, dtype=torch.float64)).shape == (4, 5, grid.n_output_dims)
    with pytest.raises(ValueError):
        grid(torch.rand(4, 2, dtype=torch.float64))


@pytest.mark.parametrize("n_dims", [2, 3, 4])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cpu_kernels_equal_the_pytorch_path(n_dims, dtype):
    """The fused CPU kernels and the PyTorch path (the one CUDA runs) agree on values and gradients."""
    grid = small_grid(n_dims, dtype)
    points = torch.rand(500, n_dims, dtype=dtype, generator=torch.Generator().manual_seed(3))
    upstream = torch.randn(500, grid.n_output_dims, dtype=dtype)

    def run() -> tuple[torch.Tensor, ...]:
        x = points.clone().requires_grad_()
        out = grid(x)
        return (out, *torch.autograd.grad((out * upstream).sum(), (grid.table, x)))

    kernels = run()
    with pytorch_path_on_cpu():
        pytorch = run()
    tolerance = 1e-5 if dtype == torch.float32 else 1e-12
    for a, b in zip(kernels, pytorch, strict=True):
        assert torch.allclose(a, b, atol=tolerance, rtol=tolerance)


def test_cpu_kernels_give_the_same_bits_whatever_the_thread_count():
    grid = HashGrid(3, n_levels=6, log2_hashmap_size=12, base_resolution=4)
    points = torch.rand(5000, 3, generator=torch.Generator().manual_seed(4), requires_grad=True)
    results = []
    previous = numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            out = grid(points)
            results.append((out, *torch.autograd.grad(out.square().sum(), (grid.table, points))))
    finally:
        numba.set_num_threads(previous)
    for a, b in zip(*results, strict=True):
        assert torch.equal(a, b)


def test_cpu_kernels_reject_level_blocks_that_do_not_tile_the_table():
    """The table-gradient kernel zeroes only the level blocks, so rows outside them would hold garbage."""
    grid = small_grid(3, dtype=torch.float32)
    points = torch.rand(10, 3)
    short = [*grid.level_blocks[:-1], (grid.level_blocks[-1][0], grid.level_blocks[-1][1] - 1)]
    with pytest.raises(ValueError, match="cover"):
        interpolate_grid(points, grid.table, grid.geometry, short, grid)


def test_the_kernels_leave_torchs_thread_count_as_it_was():
    """Numba's OpenMP pool starts at the process's first parallel kernel and shares torch's OpenMP runtime:
    a thread count set in torch before that must hold after it (a fresh process, so the pool starts here)."""
    probe = (
        "import torch\n"
        "torch.set_num_threads(1)\n"
        "assert torch.get_num_threads() == 1\n"  # read, as `torch_threads` does: then Numba resets it
        "from workers.nn.encodings.hashgrid import HashGrid\n"
        "grid = HashGrid(3, n_levels=4, log2_hashmap_size=10, base_resolution=4)\n"
        "points = torch.rand(4096, 3, requires_grad=True)\n"
        "grid(points).sum().backward()\n"
        "print(torch.get_num_threads())\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]), "OMP_NUM_THREADS": "2"}
    env["NUMBA_NUM_THREADS"] = "2"
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.split()[-1] == "1"
