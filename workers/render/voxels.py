"""Binary surface voxels of a triangle mesh and the ray walk through them (3D DDA).

Used by neural geometry models (LSNIF's encoder input, neural LODs): a mesh in its own local space is
voxelised at any resolution inside a padded box, and a batch of rays is walked through the voxels with
Amanatides-Woo, vectorised over rays.

Voxels are closed boxes: a triangle that only touches a voxel (a vertex on its corner, a face lying on its
face) occupies it. The overlap test is exact (Akenine-Möller's separating axis test in float64), so
geometry exactly on voxel faces marks the voxels on both sides and degenerate triangles (segments and
points) still mark the voxels they touch.

The walk records *boundary points*: the ray's segment inside the box is cut by every voxel plane it
crosses; a cut (or the segment's start or end) is recorded when the voxel just before or just after it is
occupied. Cuts at equal t (a ray through a voxel edge or corner) are one cut, and voxels the ray only
touches in a line or a point are not entered; a ray lying in a voxel plane walks the voxels on the
plane's upper side. Every plane coordinate is computed once by the same
expression (`plane`), so the walk and a brute-force reference agree bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from workers.render.jit import njit

TRIANGLE_CHUNK = 1 << 16
OVERLAP_SLACK = 1e-9  # relative to the voxel size: closed boxes survive float64 rounding


@dataclass(frozen=True)
class VoxelGrid:
    """Occupancy [R, R, R] (index order x, y, z) of cubical-cell boxes over [lo, lo + R * size]."""

    lo: np.ndarray  # (3,) float64
    size: np.ndarray  # (3,) float64 voxel edge lengths (> 0)
    occupied: np.ndarray  # (R, R, R) bool

    @property
    def resolution(self) -> int:
        return self.occupied.shape[0]

    @property
    def hi(self) -> np.ndarray:
        return self.plane(np.full(3, self.resolution))

    @property
    def bounds(self) -> np.ndarray:
        return np.stack([self.lo, self.hi])

    def plane(self, index: np.ndarray) -> np.ndarray:
        """Coordinates of voxel planes `index` (..., 3): the one expression every user of a plane shares."""
        return self.lo + index * self.size

    def normalize(self, points: np.ndarray) -> np.ndarray:
        """Points in box coordinates [0, 1]^3."""
        return (points - self.lo) / (self.size * self.resolution)


def padded_bounds(vertices: np.ndarray, resolution: int, pad_voxels: float = 0.5) -> np.ndarray:
    """The mesh's AABB grown by `pad_voxels` voxels of its longest side on every axis.

    The padding keeps surfaces off the outer faces (rays entering the box meet empty voxels first) and
    gives flat meshes a thickness, so a plane becomes a box one or two voxels thick.
    """
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    if len(vertices) == 0:
        return np.array([[-1.0] * 3, [1.0] * 3])
    lo, hi = vertices.min(0), vertices.max(0)
    longest = float((hi - lo).max())
    scale = max(longest, float(np.abs(vertices).max()) * 1e-9, 1e-12)
    pad = pad_voxels * scale / resolution
    return np.stack([lo - pad, hi + pad])


def voxelize(
    vertices: np.ndarray, faces: np.ndarray, resolution: int, bounds: np.ndarray | None = None
) -> VoxelGrid:
    """Voxels of `bounds` (default: `padded_bounds`) that the triangles overlap, by an exact SAT test."""
    if resolution < 1:
        raise ValueError(f"the voxel resolution must be at least 1, got {resolution}")
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if bounds is None:
        bounds = padded_bounds(vertices[faces.reshape(-1)] if len(faces) else vertices, resolution)
    lo, hi = np.asarray(bounds, np.float64)
    if not np.all(hi > lo):
        raise ValueError(f"the voxel box must have a positive size on every axis, got {lo} .. {hi}")
    grid = VoxelGrid(lo, (hi - lo) / resolution, np.zeros((resolution,) * 3, bool))
    for start in range(0, len(faces), TRIANGLE_CHUNK):
        _mark_overlaps(grid, vertices[faces[start : start + TRIANGLE_CHUNK]])
    return grid


def _mark_overlaps(grid: VoxelGrid, triangles: np.ndarray) -> None:
    """Set the voxels each triangle (T, 3, 3) overlaps: candidates from its bounding box, then SAT."""
    r = grid.resolution
    local = (triangles - grid.lo) / grid.size  # voxel units: voxel (i, j, k) is [i, i+1] x ...
    first = np.clip(np.floor(local.min(1)).astype(np.int64), 0, r - 1)
    last = np.clip(np.floor(local.max(1)).astype(np.int64), 0, r - 1)
    # A triangle touching a plane from below also touches the voxel above it (closed boxes).
    first = np.maximum(first - (np.floor(local.min(1)) == local.min(1)), 0)
    inside = np.all((local.max(1) >= 0) & (local.min(1) <= r), axis=1)
    first, last, local = first[inside], last[inside], local[inside]
    extent = last - first + 1
    counts = extent.prod(1)
    owner = np.repeat(np.arange(len(local)), counts)
    rank = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ex = extent[owner]
    offset = np.stack([rank % ex[:, 0], (rank // ex[:, 0]) % ex[:, 1], rank // (ex[:, 0] * ex[:, 1])], 1)
    cell = first[owner] + offset
    hit = triangle_box_overlap(local[owner] - (cell + 0.5)[:, None, :], np.full(3, 0.5))
    cell = cell[hit]
    grid.occupied[cell[:, 0], cell[:, 1], cell[:, 2]] = True


def triangle_box_overlap(triangles: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Whether triangles (N, 3, 3), given relative to a box's centre, touch the closed box of half-size
    `half` (3,): Akenine-Möller's 13 separating axes. Zero axes (degenerate triangles) never separate."""
    eps = OVERLAP_SLACK * float(half.max())
    overlap = np.all(
        (triangles.min(1) <= half + eps) & (triangles.max(1) >= -half - eps), axis=1
    )  # the three box normals
    edges = np.roll(triangles, -1, axis=1) - triangles
    normal = np.cross(edges[:, 0], edges[:, 1])
    axes = [normal] + [np.cross(np.eye(3)[a], edges[:, e]) for a in range(3) for e in range(3)]
    for axis in axes:
        projected = np.einsum("nvk,nk->nv", triangles, axis)
        radius = np.abs(axis) @ half
        scale = np.abs(axis).sum(1)
        overlap &= (projected.min(1) <= radius + eps * scale) & (projected.max(1) >= -radius - eps * scale)
    return overlap


@dataclass
class BoundaryPoints:
    """The walk of N rays through a `VoxelGrid`, up to H boundary points each, zero-filled."""

    points: np.ndarray  # (N, H, 3) positions in the grid's space, ordered along the ray
    t: np.ndarray  # (N, H) ray parameters of the points
    count: np.ndarray  # (N,) points recorded (<= H)
    t_near: np.ndarray  # (N,) start of the ray's segment inside the box (>= 0)
    t_far: np.ndarray  # (N,) end of that segment; t_far < t_near where the ray misses the box
    truncated: np.ndarray  # (N,) all H slots filled before the walk ended: later points were dropped

    @property
    def in_box(self) -> np.ndarray:
        return self.t_far >= self.t_near

    def take(self, rows: np.ndarray) -> BoundaryPoints:
        """The walks of the rays `rows`."""
        return BoundaryPoints(*(getattr(self, f.name)[rows] for f in fields(self)))


def clip_to_box(
    grid: VoxelGrid, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(t_near, t_far) of the rays' segments [0, t_max] inside the closed box (slab test).

    A direction component of zero constrains nothing when the origin lies within that slab (a ray
    grazing a face counts as inside) and misses otherwise.
    """
    n = len(origins)
    t_near = np.zeros(n)
    t_far = np.full(n, np.inf) if t_max is None else np.asarray(t_max, np.float64).copy()
    lo, hi = grid.lo, grid.hi
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis in range(3):
            o, d = origins[:, axis], directions[:, axis]
            moving = d != 0
            t0 = (lo[axis] - o) / d
            t1 = (hi[axis] - o) / d
            near = np.where(moving, np.minimum(t0, t1), -np.inf)
            far = np.where(moving, np.maximum(t0, t1), np.inf)
            outside = ~moving & ((o < lo[axis]) | (o > hi[axis]))
            t_near = np.maximum(t_near, near)
            t_far = np.where(outside, -np.inf, np.minimum(t_far, far))
    return t_near, t_far


def check_rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 (N, 3) copies; a clear error for non-finite values or a zero-length direction."""
    origins = np.asarray(origins, np.float64).reshape(-1, 3)
    directions = np.asarray(directions, np.float64).reshape(-1, 3)
    if len(origins) != len(directions):
        raise ValueError(f"{len(origins)} origins but {len(directions)} directions")
    if not (np.isfinite(origins).all() and np.isfinite(directions).all()):
        raise ValueError("ray origins and directions must be finite")
    if len(directions) and not np.all(np.abs(directions).max(1) > 0):
        raise ValueError("a ray direction has zero length; every ray needs a non-zero direction")
    return origins, directions


def start_cell(grid: VoxelGrid, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The voxel a walk at o + t d (inside the box) is in: on a voxel plane, the one the ray moves into."""
    start = o + t[:, None] * d
    cell = np.clip(np.floor((start - grid.lo) / grid.size).astype(np.int64), 0, grid.resolution - 1)
    on_lower_plane = (grid.plane(cell) == start) & (d < 0)
    return np.where(on_lower_plane & (cell > 0), cell - 1, cell)


def boundary_points(
    grid: VoxelGrid,
    origins: np.ndarray,
    directions: np.ndarray,
    max_points: int,
    t_max: np.ndarray | None = None,
) -> BoundaryPoints:
    """Walk every ray (Amanatides-Woo) and record up to `max_points` boundary points (module docstring).

    Directions need not be unit length; `t` is in units of the given direction.
    """
    origins, directions = check_rays(origins, directions)
    n = len(origins)
    t_near, t_far = clip_to_box(grid, origins, directions, t_max)
    out = BoundaryPoints(
        np.zeros((n, max_points, 3)), np.zeros((n, max_points)), np.zeros(n, np.int64), t_near, t_far,
        np.zeros(n, bool),
    )  # fmt: skip
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    live = np.flatnonzero(t_far >= t_near)
    cells = start_cell(grid, origins[live], directions[live], t_near[live])
    _walk_rays(
        _f64(grid.lo), _f64(grid.size), grid.occupied, origins, directions, live, cells, t_near, t_far,
        out.points, out.t, out.count, out.truncated,
    )  # fmt: skip
    return out


@njit(cache=True, nogil=True, fastmath=False)
def _walk_rays(
    lo, size, occupied, origins, directions, live, cells, t_near, t_far, points, t, count, truncated
):
    """The walk of `boundary_points`, one ray at a time from its start cell; writes each ray's points."""
    r, max_points = occupied.shape[0], points.shape[1]
    t_axis = np.empty(3)
    for j in range(len(live)):
        i = live[j]
        o, d, cell = origins[i], directions[i], cells[j].copy()
        t_cur, t_end = t_near[i], t_far[i]
        previous = False  # whether the voxel before t_cur is occupied
        while True:
            # Next plane crossing per axis, and the first of them (capped by the segment's end).
            for a in range(3):
                plane = lo[a] + (cell[a] + (1 if d[a] > 0 else 0)) * size[a]
                t_axis[a] = (plane - o[a]) / d[a] if d[a] != 0 else np.inf
            t_next = min(t_axis[0], t_axis[1], t_axis[2], t_end)
            entered = t_next > t_cur  # a voxel entered for a positive length, not just touched
            inside = 0 <= cell[0] < r and 0 <= cell[1] < r and 0 <= cell[2] < r
            occupied_now = entered and inside and occupied[cell[0], cell[1], cell[2]]
            if entered and (previous or occupied_now):
                _record(points, t, count, i, o, d, t_cur)
            if entered:
                previous, t_cur = occupied_now, t_next
            for a in range(3):
                if t_axis[a] <= t_next:
                    cell[a] += 1 if d[a] > 0 else -1
            finished = t_cur >= t_end or not (0 <= cell[0] < r and 0 <= cell[1] < r and 0 <= cell[2] < r)
            full = count[i] >= max_points
            if finished and previous and not full:
                _record(points, t, count, i, o, d, t_cur)
            if full and not (finished and not previous):
                truncated[i] = True
            if finished or full:
                break


@njit(cache=True, nogil=True, fastmath=False)  # no IR inlining: as `workers.render.kernels.scalar`
def _record(points, t, count, i, o, d, t_at) -> None:
    """Append the point at t_at to ray i if it still has room."""
    k = count[i]
    if k < points.shape[1]:
        for a in range(3):
            points[i, k, a] = o[a] + t_at * d[a]
        t[i, k] = t_at
        count[i] = k + 1


def _f64(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array, np.float64)


def coarsen(occupied: np.ndarray) -> np.ndarray:
    """The occupancy one level coarser (R/2 per side, R even): a voxel is occupied when any child is."""
    r = occupied.shape[0]
    if r % 2 or occupied.shape != (r, r, r):
        raise ValueError(f"only a cubic grid of even resolution can be coarsened, got {occupied.shape}")
    return occupied.reshape(r // 2, 2, r // 2, 2, r // 2, 2).any(axis=(1, 3, 5))


@dataclass
class OccupiedVoxels:
    """The first occupied voxel each ray enters for a positive length within its segment [t_min, t_max]."""

    found: np.ndarray  # (N,) bool
    cell: np.ndarray  # (N, 3) int64 voxel index where found
    t_enter: np.ndarray  # (N,) where the ray enters it (t_min when it starts inside); inf where not found
    t_exit: np.ndarray  # (N,) where the ray leaves it (or t_max)


def first_occupied(
    grid: VoxelGrid, origins: np.ndarray, directions: np.ndarray, t_min: np.ndarray, t_max: np.ndarray
) -> OccupiedVoxels:
    """Walk every ray (Amanatides-Woo, same planes and start-cell rule as `boundary_points`) from t_min
    until it enters an occupied voxel; vectorised over rays, finished rays drop out of the loop."""
    n, r = len(origins), grid.resolution
    out = OccupiedVoxels(
        np.zeros(n, bool), np.zeros((n, 3), np.int64), np.full(n, np.inf), np.full(n, np.inf)
    )
    t_near, t_far = clip_to_box(grid, origins, directions, t_max)
    t_near = np.maximum(t_near, t_min)
    rows = np.flatnonzero(t_far > t_near)
    o, d = origins[rows], directions[rows]
    t_cur, t_end = t_near[rows], t_far[rows]
    step = np.where(d > 0, 1, -1).astype(np.int64)
    cell = start_cell(grid, o, d, t_cur)
    safe_d = np.where(d != 0, d, 1.0)
    while len(rows):
        t_axis = np.where(d != 0, (grid.plane(cell + (step > 0)) - o) / safe_d, np.inf)
        t_next = np.minimum(t_axis.min(1), t_end)
        hit = (t_next > t_cur) & grid.occupied[cell[:, 0], cell[:, 1], cell[:, 2]]
        if hit.any():
            at = rows[hit]
            out.found[at], out.cell[at] = True, cell[hit]
            out.t_enter[at], out.t_exit[at] = t_cur[hit], t_next[hit]
        t_cur = t_next
        cell = cell + step * (t_axis <= t_next[:, None])
        keep = ~hit & (t_cur < t_end) & np.all((cell >= 0) & (cell < r), axis=1)
        rows, o, d, t_cur, t_end = rows[keep], o[keep], d[keep], t_cur[keep], t_end[keep]
        step, cell, safe_d = step[keep], cell[keep], safe_d[keep]
    return out
