"""Surface voxelisation and the voxel walk against brute-force references.

The overlap reference clips each triangle against each voxel (Sutherland-Hodgman), an algorithm
independent of the separating-axis test; the walk reference lists every plane crossing of the segment,
sorts them and looks up the voxel at each interval's midpoint.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.render.voxels import VoxelGrid, boundary_points, clip_to_box, padded_bounds, voxelize


def clipped_polygon(polygon: list[np.ndarray], lo: np.ndarray, hi: np.ndarray, eps: float) -> bool:
    """Whether the polygon keeps any point after clipping by the six (slightly grown) box planes."""
    for axis in range(3):
        for bound, sign in ((lo[axis] - eps, 1.0), (hi[axis] + eps, -1.0)):
            kept: list[np.ndarray] = []
            for i, a in enumerate(polygon):
                b = polygon[(i + 1) % len(polygon)]
                da, db = sign * (a[axis] - bound), sign * (b[axis] - bound)
                if da >= 0:
                    kept.append(a)
                if (da >= 0) != (db >= 0) and da != db:
                    kept.append(a + (b - a) * (da / (da - db)))
            polygon = kept
            if not polygon:
                return False
    return True


def brute_force_occupancy(vertices, faces, grid: VoxelGrid, eps: float = 1e-9) -> np.ndarray:
    r = grid.resolution
    occupied = np.zeros((r,) * 3, bool)
    for tri in vertices[faces]:
        for idx in np.ndindex(r, r, r):
            lo = grid.plane(np.array(idx))
            hi = grid.plane(np.array(idx) + 1)
            if clipped_polygon(list(tri), lo, hi, eps * float(grid.size.max())):
                occupied[idx] = True
    return occupied


def brute_force_walk(grid: VoxelGrid, o: np.ndarray, d: np.ndarray, h: int) -> list[np.ndarray]:
    t_near, t_far = clip_to_box(grid, o[None], d[None])
    t_near, t_far = float(t_near[0]), float(t_far[0])
    if t_far < t_near:
        return []
    r = grid.resolution
    cuts = {t_near, t_far}
    for axis in range(3):
        if d[axis] != 0:
            for k in range(r + 1):
                t = (grid.plane(np.full(3, k))[axis] - o[axis]) / d[axis]
                if t_near < t < t_far:
                    cuts.add(t)
    cuts = sorted(cuts)
    occupied = []
    for a, b in itertools.pairwise(cuts):
        mid = o + 0.5 * (a + b) * d
        cell = np.clip(np.floor((mid - grid.lo) / grid.size).astype(int), 0, r - 1)
        occupied.append(bool(grid.occupied[tuple(cell)]))
    points = []
    for i, t in enumerate(cuts):
        before = occupied[i - 1] if i > 0 else False
        after = occupied[i] if i < len(occupied) else False
        if before or after:
            points.append(o + t * d)
    return points[:h]


def random_mesh(rng, n=12):
    vertices = rng.uniform(-1, 1, (3 * n, 3))
    return vertices, np.arange(3 * n).reshape(n, 3)


def test_exact_overlap_matches_clipping_reference():
    rng = np.random.default_rng(1)
    vertices, faces = random_mesh(rng, 10)
    vertices *= 0.3 * rng.uniform(0.1, 1, (len(vertices), 1))  # small and large triangles
    grid = voxelize(vertices, faces, 5)
    assert np.array_equal(grid.occupied, brute_force_occupancy(vertices, faces, grid))


def test_overlap_contains_every_sampled_surface_point():
    rng = np.random.default_rng(2)
    vertices, faces = random_mesh(rng, 40)
    grid = voxelize(vertices, faces, 16)
    u = rng.random((40, 500, 2))
    u = np.where(u.sum(-1, keepdims=True) > 1, 1 - u, u)
    tri = vertices[faces]
    points = tri[:, None, 0] + u[..., :1] * (tri[:, None, 1] - tri[:, None, 0])
    points += u[..., 1:] * (tri[:, None, 2] - tri[:, None, 0])
    cells = np.floor((points.reshape(-1, 3) - grid.lo) / grid.size).astype(int)
    assert grid.occupied[tuple(cells.T)].all()
    assert grid.occupied.sum() < grid.occupied.size  # and not simply everything


def test_geometry_exactly_on_voxel_faces_marks_both_sides():
    # A square in the plane x = 0 of a box [-1, 1]^3 at resolution 4: x = 0 is the plane between voxels 1, 2.
    vertices = np.array([[0, -0.9, -0.9], [0, 0.9, -0.9], [0, 0.9, 0.9], [0, -0.9, 0.9]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    grid = voxelize(vertices, faces, 4, bounds=np.array([[-1.0] * 3, [1.0] * 3]))
    xs = np.flatnonzero(grid.occupied.any(axis=(1, 2)))
    assert list(xs) == [1, 2]
    assert grid.occupied[1].all() and grid.occupied[2].all()


def test_flat_object_gets_a_thin_box_and_one_voxel_layer():
    vertices = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    grid = voxelize(vertices, faces, 8, bounds=padded_bounds(vertices, 8, pad_voxels=0.25))
    assert np.all(grid.size > 0)
    layers = np.flatnonzero(grid.occupied.any(axis=(0, 2)))
    assert len(layers) in (1, 2)  # one layer, or the two touching the plane when it falls on a voxel face
    assert grid.occupied.sum() == 8 * 8 * len(layers)


def test_empty_and_degenerate_meshes():
    empty = voxelize(np.zeros((0, 3)), np.zeros((0, 3), int), 4)
    assert not empty.occupied.any()
    # A zero-area sliver (a segment) and a point-triangle still mark what they touch, nothing more.
    vertices = np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.9], [0.5, 0.5, 0.5], [0.3, 0.6, 0.2]])
    faces = np.array([[0, 1, 2], [3, 3, 3]])
    bounds = np.array([[0.0] * 3, [1.0] * 3])
    grid = voxelize(vertices, faces, 4, bounds=bounds)
    assert np.array_equal(grid.occupied, brute_force_occupancy(vertices, faces, grid))
    diagonal = {(i, i, i) for i in range(4)}
    assert diagonal <= set(map(tuple, np.argwhere(grid.occupied)))
    assert grid.occupied[1, 2, 0]  # the point (0.3, 0.6, 0.2)


def assert_walk_matches(grid, origins, directions, h):
    result = boundary_points(grid, origins, directions, h)
    for i, (o, d) in enumerate(zip(origins, directions, strict=True)):
        expected = brute_force_walk(grid, o, d, h)
        assert result.count[i] == len(expected), (i, o, d)
        if expected:
            np.testing.assert_allclose(result.points[i, : len(expected)], expected, rtol=0, atol=1e-12)
        assert not result.points[i, len(expected) :].any()
    return result


@pytest.fixture
def random_grid():
    rng = np.random.default_rng(3)
    occupied = rng.random((8, 8, 8)) < 0.3
    return VoxelGrid(np.array([-1.0, -1.0, -1.0]), np.full(3, 0.25), occupied)


def test_walk_matches_brute_force_on_random_rays(random_grid):
    rng = np.random.default_rng(4)
    n = 300
    origins = rng.uniform(-3, 3, (n, 3))
    origins[:100] = rng.uniform(-0.99, 0.99, (100, 3))  # starting inside the box
    directions = rng.normal(size=(n, 3))
    directions[200:250, 0] = 0.0  # axis-parallel in one or two components
    directions[250:300, :2] = 0.0
    assert_walk_matches(random_grid, origins, directions, h=64)


def test_walk_along_edges_corners_and_planes(random_grid):
    # Exactly representable coordinates: the planes are multiples of 1/4, so ties are exact.
    origins = np.array(
        [
            [-2.0, -2.0, -2.0],  # the main diagonal, through every voxel corner
            [-2.0, -0.5, -0.25],  # along an edge (y, z on planes), x-parallel
            [-0.5, -2.0, 0.0],  # in the plane z = 0, diagonal in x-y through corners
            [-1.0, -1.0, -3.0],  # along the box's outer edge: grazing
            [0.125, 0.125, 0.125],  # starting inside a voxel, axis-parallel
            [0.25, 0.5, -0.75],  # starting on a corner
            [5.0, 5.0, 5.0],  # missing the box
        ]
    )
    directions = np.array(
        [[1, 1, 1], [1, 0, 0], [1, 1, 0], [0, 0, 1], [0, -1, 0], [-1, 1, 0.5], [1, 0, 0]], float
    )
    result = assert_walk_matches(random_grid, origins, directions, h=64)
    assert result.count[-1] == 0 and not result.in_box[-1]


def test_very_long_and_very_short_rays(random_grid):
    origins = np.array([[-1e6, 0.1, 0.2], [0.1, 0.2, 0.3]])
    directions = np.array([[1.0, 1e-7, 0.0], [1e-9, 2e-9, -1e-9]])
    assert_walk_matches(random_grid, origins, directions, h=64)


def test_more_occupied_voxels_than_points_truncates_in_order():
    grid = VoxelGrid(np.zeros(3), np.ones(3), np.ones((32, 32, 32), bool))
    o, d = np.array([[-1.0, 0.5, 0.5]]), np.array([[1.0, 0.0, 0.0]])
    result = boundary_points(grid, o, d, max_points=18)
    assert result.count[0] == 18 and result.truncated[0]
    np.testing.assert_array_equal(result.points[0, :, 0], np.arange(18.0))
    full = boundary_points(grid, o, d, max_points=64)
    assert full.count[0] == 33 and not full.truncated[0]


def test_segment_limits_and_bad_rays(random_grid):
    o, d = np.array([[-2.0, 0.1, 0.1]]), np.array([[1.0, 0.0, 0.0]])
    short = boundary_points(random_grid, o, d, 64, t_max=np.array([1.5]))
    assert short.t_far[0] == 1.5 and np.all(short.t[0, : short.count[0]] <= 1.5)
    with pytest.raises(ValueError, match="zero length"):
        boundary_points(random_grid, o, np.zeros((1, 3)), 8)
    with pytest.raises(ValueError, match="finite"):
        boundary_points(random_grid, np.array([[np.nan, 0, 0]]), d, 8)
