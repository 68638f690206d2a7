"""Surface voxelisation and the voxel walk against brute-force references.

The overlap reference clips each triangle against each voxel (Sutherland-Hodgman), an algorithm
independent of the separating-axis test; the walk reference lists every plane crossing of the segment,
sorts them and looks up the voxel at each interval's midpoint.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from workers.render.voxels import (
    VoxelGrid,
    boundary_points,
    clip_to_box,
    coarsen,
    first_occupied,
    padded_bounds,
    voxelize,
)


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


# --------------------------------------------------------------------------- first_occupied, coarsen


def brute_force_first_occupied(grid: VoxelGrid, o, d, t_min: float, t_max: float):
    """(cell, t_enter, t_exit) of the first occupied voxel on [t_min, t_max], or None: every plane
    crossing of the clipped segment, sorted, and the voxel at each positive-length interval's midpoint."""
    t_near, t_far = clip_to_box(grid, o[None], d[None], np.array([t_max]))
    t0, t1 = max(float(t_near[0]), t_min), float(t_far[0])
    if not t1 > t0:
        return None
    r = grid.resolution
    cuts = {t0, t1}
    for axis in range(3):
        if d[axis] != 0:
            for k in range(r + 1):
                t = (grid.plane(np.full(3, k))[axis] - o[axis]) / d[axis]
                if t0 < t < t1:
                    cuts.add(t)
    for a, b in itertools.pairwise(sorted(cuts)):
        mid = o + 0.5 * (a + b) * d
        cell = np.clip(np.floor((mid - grid.lo) / grid.size).astype(int), 0, r - 1)
        if grid.occupied[tuple(cell)]:
            return cell, a, b
    return None


def assert_first_occupied_matches(grid, origins, directions, t_min, t_max):
    result = first_occupied(grid, origins, directions, t_min, t_max)
    for i in range(len(origins)):
        expected = brute_force_first_occupied(grid, origins[i], directions[i], t_min[i], t_max[i])
        if expected is None:
            assert not result.found[i], (i, origins[i], directions[i])
            assert result.t_enter[i] == np.inf
            continue
        cell, t_enter, t_exit = expected
        assert result.found[i], (i, origins[i], directions[i])
        assert tuple(result.cell[i]) == tuple(cell), (i, origins[i], directions[i])
        assert result.t_enter[i] == pytest.approx(t_enter, rel=0, abs=1e-12)
        assert result.t_exit[i] == pytest.approx(t_exit, rel=0, abs=1e-12)
    return result


def test_first_occupied_matches_brute_force_on_random_rays_and_windows(random_grid):
    rng = np.random.default_rng(5)
    n = 400
    origins = rng.uniform(-3, 3, (n, 3))
    origins[:150] = rng.uniform(-0.99, 0.99, (150, 3))  # starting inside the box
    directions = rng.normal(size=(n, 3))
    directions[150:250] = rng.uniform(-1, 1, (100, 3)) - origins[150:250]  # from outside, aimed at the box
    directions[250:300, 1] = 0.0  # axis-parallel in one or two components
    directions[300:350, ::2] = 0.0
    t_min = np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0, 3, n))
    t_max = np.where(rng.random(n) < 0.5, np.inf, t_min + rng.uniform(0, 3, n))
    t_max[350:360] = t_min[350:360] - 0.1  # empty windows
    result = assert_first_occupied_matches(random_grid, origins, directions, t_min, t_max)
    assert 0.25 < result.found.mean() < 0.9  # both outcomes are exercised
    assert not result.found[350:360].any()

    # An independent check by dense point samples: nothing occupied before t_enter, the found cell between
    # t_enter and t_exit (points exactly on planes have probability zero).
    for i in np.flatnonzero(np.isfinite(t_max))[:100]:
        ts = np.linspace(t_min[i], t_max[i], 2001)[1:-1]
        points = origins[i] + ts[:, None] * directions[i]
        inside = np.all((points > random_grid.lo) & (points < random_grid.hi), axis=1)
        cells = np.floor((points[inside] - random_grid.lo) / random_grid.size).astype(int)
        occupied, ts = random_grid.occupied[tuple(cells.T)], ts[inside]
        before = ts < result.t_enter[i]
        assert not occupied[before].any(), i
        within = ~before & (ts < result.t_exit[i])
        assert np.all(cells[within] == result.cell[i]), i


def test_first_occupied_rays_in_planes_along_edges_and_axes(random_grid):
    # Exactly representable coordinates: planes are multiples of 1/4, so ties are exact.
    origins = np.array(
        [
            [-2.0, -2.0, -2.0],  # the main diagonal, through every voxel corner
            [-2.0, -0.5, -0.25],  # along an edge (y, z on planes), x-parallel
            [-0.5, -2.0, 0.0],  # in the plane z = 0, diagonal in x-y through corners
            [-1.0, -1.0, -3.0],  # along the box's outer edge: grazing
            [1.0, 0.3, -3.0],  # in the box's upper x face
            [0.25, 0.5, -0.75],  # starting on a corner
            [0.3, 0.5, 0.1],  # starting on a plane (y), moving down: the voxel below
            [5.0, 5.0, 5.0],  # missing the box
            [-3.0, 0.1, 0.2],  # pointing away from the box
        ]
    )
    directions = np.array(
        [[1, 1, 1], [1, 0, 0], [1, 1, 0], [0, 0, 1], [0, 0, 1], [-1, 1, 0.5], [0.2, -1, 0.1], [1, 0, 0],
         [-1, 0, 0]],
        float,
    )  # fmt: skip
    n = len(origins)
    result = assert_first_occupied_matches(random_grid, origins, directions, np.zeros(n), np.full(n, np.inf))
    assert not result.found[-2:].any() and np.all(result.t_enter[-2:] == np.inf)


def test_first_occupied_starting_inside_an_occupied_voxel_enters_at_t_min():
    occupied = np.zeros((4, 4, 4), bool)
    occupied[1, 2, 1] = occupied[3, 2, 1] = True
    grid = VoxelGrid(np.zeros(3), np.ones(3), occupied)
    o = np.array([[1.25, 2.5, 1.5]] * 4)
    d = np.array([[1.0, 0.0, 0.0]] * 4)
    t_min = np.array([0.0, 0.5, 1.0, 0.5])
    t_max = np.array([np.inf, np.inf, np.inf, 1.2])
    result = first_occupied(grid, o, d, t_min, t_max)
    # From inside voxel (1, 2, 1): entered at t_min, left at x = 2.
    assert result.found[0] and tuple(result.cell[0]) == (1, 2, 1)
    assert result.t_enter[0] == 0.0 and result.t_exit[0] == 0.75
    assert result.found[1] and tuple(result.cell[1]) == (1, 2, 1) and result.t_enter[1] == 0.5
    # t_min past the first voxel: the next occupied one, (3, 2, 1), entered at x = 3.
    assert tuple(result.cell[2]) == (3, 2, 1) and result.t_enter[2] == 1.75 and result.t_exit[2] == 2.75
    # A window ending inside the first voxel's neighbour finds nothing beyond t_max... but the first voxel
    # itself, cut short at t_max when t_max falls inside it.
    assert result.found[3] and result.t_exit[3] == 0.75
    cut = first_occupied(grid, o[:1], d[:1], np.array([0.1]), np.array([0.6]))
    assert cut.found[0] and cut.t_enter[0] == 0.1 and cut.t_exit[0] == 0.6
    empty_gap = first_occupied(grid, o[:1], d[:1], np.array([0.8]), np.array([1.7]))
    assert not empty_gap.found[0]  # x in [2.05, 2.95]: the empty voxel (2, 2, 1) only


def test_first_occupied_restarted_at_its_own_exit_never_re_enters():
    """Walking on from t_exit (as traversal does after passing a voxel) moves to the next voxel."""
    rng = np.random.default_rng(6)
    grid = VoxelGrid(
        np.array([-1.03125, -0.0625, -1.0625]), np.full(3, 2.1234567 / 16), np.ones((16,) * 3, bool)
    )
    n = 20000
    o = grid.lo + rng.random((n, 3)) * (grid.hi - grid.lo)
    d = rng.normal(size=(n, 3))
    first = first_occupied(grid, o, d, np.zeros(n), np.full(n, np.inf))
    assert first.found.all()
    again = first_occupied(grid, o, d, first.t_exit, np.full(n, np.inf))
    moved = ~np.all(again.cell == first.cell, axis=1)
    assert np.all(moved | ~again.found)
    assert np.all(again.t_enter[again.found] == first.t_exit[again.found])


def test_first_occupied_no_rays():
    grid = VoxelGrid(np.zeros(3), np.ones(3), np.ones((2, 2, 2), bool))
    result = first_occupied(grid, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    assert result.found.shape == (0,) and result.cell.shape == (0, 3)


def test_coarsen_is_the_union_of_children():
    rng = np.random.default_rng(7)
    fine = rng.random((8, 8, 8)) < 0.05
    coarse = coarsen(fine)
    assert coarse.shape == (4, 4, 4)
    for idx in np.ndindex(4, 4, 4):
        children = fine[tuple(slice(2 * i, 2 * i + 2) for i in idx)]
        assert coarse[idx] == children.any(), idx
    assert coarse.any() and not coarse.all()
    assert coarsen(coarsen(coarsen(fine))).shape == (1, 1, 1)
    assert not coarsen(np.zeros((2, 2, 2), bool)).any()
    with pytest.raises(ValueError, match="even"):
        coarsen(np.zeros((3, 3, 3), bool))
    with pytest.raises(ValueError, match="cubic"):
        coarsen(np.zeros((4, 4, 2), bool))
