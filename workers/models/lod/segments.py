"""Compiled per-row work of the lod sample source: where rays leave boxes, and the boundary pairs of
Sec. 5.1 (`workers.models.lod.sampling`), each one pass over the batch instead of a dozen NumPy passes.

float64 throughout, like `workers.render.kernels`; serial, `nogil` and cached on disk.
"""

from __future__ import annotations

import math

import numpy as np

from workers.render.jit import njit
from workers.render.kernels import uniform_sphere
from workers.render.wavefront import leave_one, offset_one

kernel = njit(cache=True, nogil=True, fastmath=False)


# helpers below: plain compiled functions, no IR-level inlining (as `workers.render.kernels.scalar`)
@kernel
def _exit_distance(lo, hi, i, o0, o1, o2, d0, d1, d2):
    """Distance along (d0, d1, d2) at which a ray from (o0, o1, o2), inside box i, leaves it (>= 0)."""
    t = math.inf
    for axis, o, d in ((0, o0, d0), (1, o1, d1), (2, o2, d2)):
        if d > 0:
            t = min(t, (hi[i, axis] - o) / d)
        elif d < 0:
            t = min(t, (lo[i, axis] - o) / d)
    return max(t, 0.0)


@kernel
def _max3(a, b, c):
    """The largest of three, NaN if any is NaN (as `workers.render.sampling.max3`)."""
    if math.isnan(a) or math.isnan(b) or math.isnan(c):
        return math.nan
    return max(a, b, c)


@kernel
def uniform_sphere_rows(u):
    """(N, 3) uniform directions from (N, 2) uniforms: `sampling.square_to_uniform_sphere` in one pass."""
    out = np.empty((len(u), 3))
    for i in range(len(u)):
        out[i, 0], out[i, 1], out[i, 2] = uniform_sphere(u[i, 0], u[i, 1])
    return out


@kernel
def voxel_ancestors(fine_keys, resolution, shifts, level):
    """(N, 3) cells at LoD level[i] of the LoD-0 voxels with row-major keys (x r + y) r + z."""
    out = np.empty((len(fine_keys), 3), np.int64)
    for i in range(len(fine_keys)):
        key, shift = fine_keys[i], shifts[level[i]]
        out[i, 0] = (key // (resolution * resolution)) >> shift
        out[i, 1] = ((key // resolution) % resolution) >> shift
        out[i, 2] = (key % resolution) >> shift
    return out


@kernel
def box_exit_rows(lo, hi, origins, directions):
    """(N,) exit distances of rays inside boxes (N, 3)."""
    out = np.empty(len(origins))
    for i in range(len(origins)):
        o, d = origins[i], directions[i]
        out[i] = _exit_distance(lo, hi, i, o[0], o[1], o[2], d[0], d[1], d[2])
    return out


@kernel
def boundary_pair_rows(grid_lo, extent, resolutions, level, cells, grow, wo, u_face, u_point):
    """Grown boxes, entry points p_o (a face picked by |wo . n|, a uniform point on it), exit points p_i
    along -wo and segment lengths of one pair per voxel (level, cell)."""
    n = len(cells)
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    p_o, p_i, length = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    for i in range(n):
        size = extent / resolutions[level[i]]
        w0, w1, w2 = abs(wo[i, 0]), abs(wo[i, 1]), abs(wo[i, 2])
        total = w0 + w1 + w2
        c0 = w0 / total
        c1 = c0 + w1 / total
        c2 = c1 + w2 / total
        u = u_face[i]
        face = min(int(u > c0) + int(u > c1) + int(u > c2), 2)
        for a in range(3):
            lo[i, a] = grid_lo[a] + cells[i, a] * size - grow * size
            hi[i, a] = lo[i, a] + (1 + 2 * grow) * size
            p_o[i, a] = lo[i, a] + u_point[i, a] * (hi[i, a] - lo[i, a])
        p_o[i, face] = hi[i, face] if wo[i, face] > 0 else lo[i, face]
        t = _exit_distance(lo, hi, i, p_o[i, 0], p_o[i, 1], p_o[i, 2], -wo[i, 0], -wo[i, 1], -wo[i, 2])
        length[i] = t
        for a in range(3):
            p_i[i, a] = p_o[i, a] - t * wo[i, a]
    return lo, hi, p_o, p_i, length


@kernel
def roulette_survivors(beta, weight, eta, u_survive, max_survival):
    """Albedo-based Russian roulette after a BSDF sample of relative IOR `eta` (1 for a reflection): beta *=
    weight / q with q = min(max(weight) * eta^2, max_survival) (in place), and the rows that survived with a
    non-zero throughput. The eta^2 undoes a transmission's 1/eta^2 radiance scaling (`workers.render.bsdf`),
    as the path tracer's roulette does (`wavefront._roulette`): a refraction into glass loses no energy, so
    it is no reason to end the path. Played before the bounce ray is traced, so only survivors' rays are."""
    keep = np.empty(len(beta), np.int64)
    n_keep = 0
    for i in range(len(beta)):
        q = _max3(weight[i, 0], weight[i, 1], weight[i, 2]) * eta[i] * eta[i]
        q = q if q < max_survival or math.isnan(q) else max_survival
        scale = 1.0 / max(q, 1e-300)
        for c in range(3):
            beta[i, c] = beta[i, c] * weight[i, c] * scale
        if u_survive[i] < q and _max3(beta[i, 0], beta[i, 1], beta[i, 2]) > 0:
            keep[n_keep] = i
            n_keep += 1
    return keep[:n_keep]


@kernel
def take_voxel_paths(survivors, t_exit, live, beta, lo, hi, origins, directions, prim, t, u, v):
    """The voxel paths (batch row, ray, throughput, box) and their hits (prim, t, u, v) that go on: the
    survivors' rays that hit the asset inside their box (`prim >= 0` and `t < t_exit`; a hit past the box
    ends the path), in one pass instead of a mask, a `flatnonzero` and ten gathers. The rays and hits
    (`t_exit`, `origins` .. `v`) are indexed like `survivors`; the paths' own arrays (`live`, `beta`, `lo`,
    `hi`) by `survivors` itself."""
    rows = np.empty(len(survivors), np.int64)
    m = 0
    for r in range(len(survivors)):
        if prim[r] >= 0 and t[r] < t_exit[r]:
            rows[m] = r
            m += 1
    out_live, out_prim = np.empty(m, live.dtype), np.empty(m, prim.dtype)
    out_o, out_d, out_beta = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    out_lo, out_hi = np.empty((m, 3)), np.empty((m, 3))
    out_t, out_u, out_v = np.empty(m, t.dtype), np.empty(m, u.dtype), np.empty(m, v.dtype)
    for j in range(m):
        r = rows[j]
        i = survivors[r]
        for c in range(3):
            out_o[j, c], out_d[j, c], out_beta[j, c] = origins[r, c], directions[r, c], beta[i, c]
            out_lo[j, c], out_hi[j, c] = lo[i, c], hi[i, c]
        out_live[j], out_prim[j], out_t[j], out_u[j], out_v[j] = live[i], prim[r], t[r], u[r], v[r]
    return out_live, out_o, out_d, out_beta, out_lo, out_hi, out_prim, out_t, out_u, out_v


@kernel
def rays_leaving_voxels(rows, wi, fs, ft, ns, position, ng, scale, lo, hi):
    """`wavefront.rays_leaving` at `rows` and where each ray leaves its voxel box, in one pass."""
    n = len(rows)
    origins, directions, t_exit = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    for j in range(n):
        i = rows[j]
        o, d = origins[j], directions[j]
        leave_one(wi[i], fs[i], ft[i], ns[i], position[i], ng[i], scale[i], o, d)
        t_exit[j] = _exit_distance(lo, hi, i, o[0], o[1], o[2], d[0], d[1], d[2])
    return origins, directions, t_exit


@kernel
def voxel_shadow_rays(f_cos, light, position, ng, scale, lo, hi):
    """Shadow rays towards the uniform directions `light` from the rows whose BSDF passes light there
    (f_cos > 0): those rows, the rays' origins offset off the surface, and where they leave the voxel box."""
    n = len(f_cos)
    lit, origins, t_max = np.empty(n, np.int64), np.empty((n, 3)), np.empty(n)
    count = 0
    for i in range(n):
        if not _max3(f_cos[i, 0], f_cos[i, 1], f_cos[i, 2]) > 0:
            continue
        p, nrm, d = position[i], ng[i], light[i]
        o0, o1, o2 = offset_one(p[0], p[1], p[2], nrm[0], nrm[1], nrm[2], d[0], d[1], d[2], scale[i])
        origins[count, 0], origins[count, 1], origins[count, 2] = o0, o1, o2
        t_max[count] = _exit_distance(lo, hi, i, o0, o1, o2, d[0], d[1], d[2])
        lit[count] = i
        count += 1
    return lit[:count], origins[:count], t_max[:count]


@kernel
def add_unblocked_throughput(value, live, lit, beta, f_cos, blocked):
    """value[live[lit]] += beta f_cos on the rows of `lit` whose shadow ray is not blocked."""
    for j in range(len(lit)):
        if blocked[j]:
            continue
        i = lit[j]
        for c in range(3):
            value[live[i], c] += beta[i, c] * f_cos[i, c]


@kernel
def take_pair_rows(rows, p_o, p_i, wo, lo, hi, length):
    """`BoundaryPairs.take` in one pass (six NumPy gathers took about 0.15 ms of a menger_sponge batch)."""
    m = len(rows)
    out_p_o, out_p_i, out_wo = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    out_lo, out_hi, out_length = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    for j in range(m):
        i = rows[j]
        for c in range(3):
            out_p_o[j, c], out_p_i[j, c], out_wo[j, c] = p_o[i, c], p_i[i, c], wo[i, c]
            out_lo[j, c], out_hi[j, c] = lo[i, c], hi[i, c]
        out_length[j] = length[i]
    return out_p_o, out_p_i, out_wo, out_lo, out_hi, out_length


@kernel
def cube_coordinates_f32(points, lo, extent):
    """`LodGrid.normalize` rounded to float32 (the networks' inputs), in one pass without temporaries."""
    out = np.empty(points.shape, np.float32)
    for i in range(len(points)):
        for c in range(3):
            out[i, c] = np.float32((points[i, c] - lo[c]) / extent)
    return out


@kernel
def voxel_centres_f32(rows, level, cells, resolutions):
    """`LodGrid.centres` of the voxels `rows` of (level, cells), rounded to float32, in one pass."""
    out = np.empty((len(rows), 3), np.float32)
    for j in range(len(rows)):
        i = rows[j]
        r = np.float64(resolutions[level[i]])
        for c in range(3):
            out[j, c] = np.float32((cells[i, c] + 0.5) / r)
    return out
