"""The `lod` kind's sparse multi-level grid (Weier et al. 2023, Sec. 4.1) against brute-force references.

LoD 0 is checked against an independent voxelisation of each level at its own resolution (a triangle
touches a closed coarse voxel iff it touches one of its eight closed children), and the coarser levels
against the union of their children computed voxel by voxel.
"""

from __future__ import annotations

import numpy as np
import pytest

from workers.models.lod.grid import DEFAULT_THRESHOLD, LodGrid
from workers.render.voxels import voxelize


def random_triangles(rng: np.random.Generator, n: int) -> np.ndarray:
    centres = rng.uniform(-1, 1, (n, 1, 3))
    return centres + rng.normal(scale=0.15, size=(n, 3, 3))


def keys_as_cells(grid: LodGrid, level: int) -> set[tuple[int, ...]]:
    return set(map(tuple, grid.cells(level)))


def test_levels_are_the_voxelisation_at_each_resolution_and_the_union_of_children():
    rng = np.random.default_rng(11)
    triangles = random_triangles(rng, 30)
    grid = LodGrid.build(triangles, [16, 8, 4, 2])
    assert grid.levels == 4 and list(grid.shifts) == [0, 1, 2, 3]
    assert 0.02 < grid.occupancy(0) < 0.5  # sparse at LoD 0
    for level, r in enumerate(grid.resolutions):
        keys = grid.keys[level]
        assert keys.dtype == np.int64 and np.all(np.diff(keys) > 0)  # sorted, unique
        assert 0 < len(keys) <= r**3
        # Independently: voxelise at this level's resolution over the same cube.
        faces = np.arange(3 * len(triangles)).reshape(-1, 3)
        cube = np.stack([grid.lo, grid.lo + grid.extent])
        direct = voxelize(triangles.reshape(-1, 3), faces, r, cube).occupied
        assert keys_as_cells(grid, level) == set(map(tuple, np.argwhere(direct)))
        # The union of the LoD-0 descendants, voxel by voxel.
        fine = keys_as_cells(grid, 0)
        shift = int(grid.shifts[level])
        union = {tuple(int(c) >> shift for c in cell) for cell in fine}
        assert keys_as_cells(grid, level) == union
    # The grid is a cube around the triangles with about half a LoD-0 voxel of padding.
    points = triangles.reshape(-1, 3)
    assert np.all(points.min(0) - grid.lo > 0.45 * grid.voxel_size(0))
    assert np.all(grid.lo + grid.extent - points.max(0) > 0.45 * grid.voxel_size(0))
    assert grid.thresholds[0].dtype == np.float32 and np.all(grid.thresholds[2] == DEFAULT_THRESHOLD)


def test_geometry_exactly_on_voxel_faces_marks_both_sides_at_every_level():
    # Squares spanning y, z in [-1, 1] at x = -9/32, 0 and 9/32: the cube is [-1.125, 1.125]^3 (padding of
    # half a LoD-0 voxel of 0.28125 = 9/32), so they lie exactly on LoD-0 voxel planes 3, 4 and 5; at
    # LoD 1, x = 0 is a plane and x = +-9/32 are inside voxels.
    def square(x):
        v = np.array([[x, -1, -1], [x, 1, -1], [x, 1, 1], [x, -1, 1]], float)
        return v[[[0, 1, 2], [0, 2, 3]]]

    triangles = np.concatenate([square(-9 / 32), square(0.0), square(9 / 32)])
    grid = LodGrid.build(triangles, [8, 4, 2, 1])
    assert np.array_equal(grid.lo, [-1.125] * 3) and grid.extent == 2.25
    expected_x = {0: [2, 3, 4, 5], 1: [1, 2], 2: [0, 1], 3: [0]}
    for level, xs in expected_x.items():
        r = grid.resolutions[level]
        cells = grid.cells(level)
        assert sorted(set(cells[:, 0])) == xs, level
        assert len(cells) == len(xs) * r * r  # every y, z: the squares span the cube but its padding


def test_degenerate_triangles_mark_what_they_touch():
    segment = np.array([[[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]])
    point = np.array([[[0.9, -0.9, 0.3]] * 3])
    grid = LodGrid.build(np.concatenate([segment, point]), [4, 2])
    # The closed voxels the diagonal t (1, 1, 1), t in [-1, 1], touches: the per-axis intervals overlap.
    planes = grid.lo[0] + grid.voxel_size(0) * np.arange(5)
    diagonal = {
        cell
        for cell in np.ndindex(4, 4, 4)
        if max(planes[list(cell)].max(), -1.0) <= min(planes[[c + 1 for c in cell]].min(), 1.0)
    }
    point_cell = tuple(np.floor((point[0, 0] - grid.lo) / grid.voxel_size(0)).astype(int))
    assert point_cell not in diagonal
    assert keys_as_cells(grid, 0) == diagonal | {point_cell}
    # A mesh that is a single point still gets a positive-size cube; the point is its centre, the corner
    # of 8 closed voxels at every even resolution.
    lonely = LodGrid.build(point, [4, 2, 1])
    assert lonely.extent > 0 and [len(k) for k in lonely.keys] == [8, 8, 1]


def test_arrays_round_trip_with_thresholds():
    rng = np.random.default_rng(12)
    grid = LodGrid.build(random_triangles(rng, 10), [8, 4, 2])
    grid.thresholds = [rng.random(len(k)).astype(np.float32) for k in grid.keys]
    arrays = grid.arrays()
    assert arrays["grid.keys.0"].dtype == np.uint32 and arrays["grid.thresholds.1"].dtype == np.float16
    back = LodGrid.from_arrays(arrays)
    assert np.array_equal(back.lo, grid.lo) and back.lo.dtype == np.float64
    assert back.extent == grid.extent and back.resolutions == grid.resolutions
    for level in range(grid.levels):
        assert np.array_equal(back.keys[level], grid.keys[level]) and back.keys[level].dtype == np.int64
        # Stored as float16: the round trip is exact up to that rounding, and no further.
        expected = grid.thresholds[level].astype(np.float16).astype(np.float32)
        assert np.array_equal(back.thresholds[level], expected)
        assert np.abs(back.thresholds[level] - grid.thresholds[level]).max() < 1e-3
    assert grid.storage_bytes() == 6 * sum(len(k) for k in grid.keys)


def test_index_and_threshold_lookup():
    rng = np.random.default_rng(13)
    grid = LodGrid.build(random_triangles(rng, 10), [8, 4])
    for level in range(grid.levels):
        n = len(grid.keys[level])
        grid.thresholds[level] = np.arange(n, dtype=np.float32) / n
        cells = grid.cells(level)
        order = rng.permutation(n)
        assert np.array_equal(grid.index(level, cells[order]), order)
        assert np.array_equal(grid.threshold(level, cells[order]), grid.thresholds[level][order])
        # Keys are (x R + y) R + z: the lookup is by position, not by the order of the axes.
        r = grid.resolutions[level]
        x, y, z = cells[0]
        assert grid.keys[level][0] == (x * r + y) * r + z
    # The dense occupancy of a level agrees with its keys; the boxes tile the cube.
    dense = grid.level_grid(1)
    assert set(map(tuple, np.argwhere(dense.occupied))) == keys_as_cells(grid, 1)
    lo, hi = grid.boxes(1, np.array([[0, 0, 0], [3, 3, 3]]))
    np.testing.assert_allclose(lo[0], grid.lo)
    np.testing.assert_allclose(hi[1], grid.lo + grid.extent)
    np.testing.assert_allclose(grid.centres(1, np.array([[0, 1, 3]])), [[0.125, 0.375, 0.875]])


def test_centres_never_coincide_across_levels():
    grid = LodGrid(np.zeros(3), 1.0, [8, 4, 2, 1], [np.zeros(1, np.int64)] * 4)
    centres = [
        grid.centres(level, np.argwhere(np.ones((r,) * 3))) for level, r in enumerate(grid.resolutions)
    ]
    everything = np.concatenate(centres)
    assert len(np.unique(everything, axis=0)) == len(everything)
    per_cell_level = grid.centres(np.array([0, 3]), np.array([[0, 0, 0], [0, 0, 0]]))
    np.testing.assert_allclose(per_cell_level, [[1 / 16] * 3, [0.5] * 3])


@pytest.mark.parametrize("resolutions", [[4, 2], [8, 2]])
def test_shifts_map_a_lod0_cell_to_its_ancestor(resolutions):
    grid = LodGrid.build(np.array([[[-1.0, -1, -1], [1, 1, 1], [1, -1, 0]]]), resolutions)
    shift = int(grid.shifts[1])
    assert resolutions[0] >> shift == resolutions[1]
