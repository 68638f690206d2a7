"""Sparse grid: equals a dense grid on its stored vertices, reads zeros elsewhere, gradients stay put."""

from __future__ import annotations

import itertools

import pytest
import torch

from workers.nn.encodings.grid import GridGeometry, interpolate_grid, pytorch_path_on_cpu
from workers.nn.encodings.hashgrid import HashGrid
from workers.nn.encodings.sparse_hashgrid import SparseHashGrid, vertices_touched


def all_vertices(side: int, n_dims: int) -> torch.Tensor:
    return torch.tensor(list(itertools.product(range(side), repeat=n_dims)))


@pytest.mark.parametrize("n_dims", [2, 3])
def test_full_vertex_set_equals_dense_grid(n_dims):
    dense = HashGrid(n_dims, n_levels=3, log2_hashmap_size=16, base_resolution=3).double()
    dense.table.data.uniform_(-1, 1)
    vertices = [all_vertices(dense.geometry.vertices_per_side(level), n_dims) for level in range(3)]
    sparse = SparseHashGrid(vertices, n_dims, base_resolution=3).double()
    for level, (start, size) in enumerate(sparse.level_blocks):
        # Dense rows are x-fastest linear keys; sparse rows are sorted by key with the same layout.
        dense_start, dense_size = dense.level_blocks[level]
        assert size == dense_size
        sparse.table.data[start : start + size] = dense.table.data[dense_start : dense_start + size]
    points = torch.rand(100, n_dims, dtype=torch.float64)
    assert torch.allclose(sparse(points), dense(points), atol=1e-12)


def sparse_with_holes() -> tuple[SparseHashGrid, torch.Tensor]:
    """A 2-level 3D grid storing only the vertices on the plane z = 1 (lattice units)."""
    geometry = GridGeometry(3, n_levels=2, base_resolution=4, per_level_scale=2.0)
    vertices = []
    for level in range(2):
        side = geometry.vertices_per_side(level)
        grid = all_vertices(side, 3)
        vertices.append(grid[grid[:, 2] == 1])
    sparse = SparseHashGrid(vertices, 3, base_resolution=4).double()
    sparse.table.data.uniform_(-1, 1)
    return sparse, torch.cat(vertices)


def test_missing_vertices_read_zero_and_get_no_gradient():
    sparse, _ = sparse_with_holes()
    far = torch.tensor([[0.5, 0.5, 0.9]], dtype=torch.float64)  # cells with z far above the stored plane
    assert torch.all(sparse(far) == 0)
    near = torch.tensor([[0.4, 0.6, 0.2]], dtype=torch.float64)
    sparse(near).sum().backward()
    grads = sparse.table.grad
    assert grads.abs().sum() > 0
    # Exactly the stored corners touched by `near` receive gradient: at most 4 of 8 per level.
    assert 0 < (grads[:, 0] != 0).sum() <= 4 * 2


def test_sparse_read_equals_dense_read_with_zeros_on_missing_vertices():
    sparse, _ = sparse_with_holes()
    dense = HashGrid(3, n_levels=2, log2_hashmap_size=20, base_resolution=4).double()
    dense.table.data.zero_()
    for level, (start, size) in enumerate(sparse.level_blocks):
        dense_start = dense.level_blocks[level][0]
        rows = sparse.level_keys(level) + dense_start
        dense.table.data[rows] = sparse.table.data[start : start + size]
    points = torch.rand(300, 3, dtype=torch.float64, requires_grad=True)
    a = sparse(points)
    b = dense(points)
    assert torch.allclose(a, b, atol=1e-12)
    grad_a = torch.autograd.grad(a.sum(), points)[0]
    grad_b = torch.autograd.grad(b.sum(), points)[0]
    assert torch.allclose(grad_a, grad_b, atol=1e-10)


def test_gradcheck_sparse_grid():
    sparse, _ = sparse_with_holes()
    points = torch.tensor([[0.31, 0.47, 0.22], [0.62, 0.12, 0.27]], dtype=torch.float64, requires_grad=True)

    def encode(x: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
        return interpolate_grid(x, table, sparse.geometry, sparse.level_blocks, sparse)

    assert torch.autograd.gradcheck(encode, (points, sparse.table))


def test_vertices_touched_cover_every_read():
    geometry = GridGeometry(3, n_levels=2, base_resolution=8, per_level_scale=2.0)
    # Points on the faces of the voxel [0.25, 0.5]^3, as LSNIF's hit points on an occupied voxel.
    face_points = torch.rand(2000, 3, dtype=torch.float64) * 0.25 + 0.25
    face_points[torch.arange(2000), torch.randint(0, 3, (2000,))] = 0.25
    touched = vertices_touched(geometry, face_points)
    sparse = SparseHashGrid(touched, 3, base_resolution=8).double()
    sparse.table.data.fill_(1.0)
    assert torch.allclose(sparse(face_points), torch.ones(2000, 4, dtype=torch.float64))
    dense_vertices = sum(geometry.vertices_per_side(level) ** 3 for level in range(2))
    assert sparse.table.shape[0] < dense_vertices / 10


def test_invalid_vertex_sets_are_rejected():
    with pytest.raises(ValueError):
        SparseHashGrid([torch.tensor([[0, 0, 17]])], 3, base_resolution=16)
    with pytest.raises(ValueError):
        SparseHashGrid([torch.zeros(0, 3, dtype=torch.long)], 3)


def test_cpu_kernels_equal_the_pytorch_path_with_missing_corners():
    sparse, _ = sparse_with_holes()
    points = torch.rand(400, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5))

    def run() -> tuple[torch.Tensor, ...]:
        x = points.clone().requires_grad_()
        out = sparse(x)
        return (out, *torch.autograd.grad(out.sin().sum(), (sparse.table, x)))

    kernels = run()
    with pytorch_path_on_cpu():
        pytorch = run()
    for a, b in zip(kernels, pytorch, strict=True):
        assert torch.allclose(a, b, atol=1e-12)


def test_loaded_keys_reach_the_cpu_kernels():
    """load_state_dict copies keys into the buffers in place; the kernels must read the new ones."""
    side = GridGeometry(3, 1, 4, 2.0).vertices_per_side(0)
    plane = all_vertices(side, 3)
    low = SparseHashGrid([plane[plane[:, 2] == 1]], 3, base_resolution=4).double()
    high = SparseHashGrid([plane[plane[:, 2] == 3]], 3, base_resolution=4).double()
    high.table.data.uniform_(-1, 1)
    points = torch.rand(200, 3, dtype=torch.float64)
    low(points)  # builds the kernels' arrays from the old keys
    low.load_state_dict(high.state_dict())
    assert torch.equal(low(points), high(points))
