"""The path tracer's per-bounce work between Embree calls, as compiled kernels over wavefront arrays.

Each kernel is one pass over the live paths doing what took a dozen NumPy operations (and as many
temporary (N, 3) arrays): surface points from hits, emission with its MIS weight, shading frames,
shadow rays of next-event estimation, and the next segment's rays with Russian roulette and compaction.
BSDFs and light selection are compiled in their own modules (`workers.render.bsdfs`,
`workers.render.lights`); what stays in NumPy is what varies by plugin (textures, environment maps,
aggregates, observers).

Precision (`workers.render.kernels`): float64 arithmetic and arrays; Embree receives float32 rays.
Kernels are serial, `nogil=True`: the renderer's threads run one work item each, and a kernel's result
depends only on its inputs, so images are identical for a seed whatever the thread count.
"""

from __future__ import annotations

import math

import numpy as np

from workers.render import kernels as k
from workers.render.environment import lookup_rows
from workers.render.jit import njit

RAY_OFFSET = 2e-5  # relative to the magnitude of the hit triangle's coordinates

# Columns of a triangle's record (`triangle_records`), and what its EMITS column holds
NG, SCALE, SMOOTH, MATERIAL, EMITS = 0, 3, 4, 5, 6
NOT_EMITTING, FRONT_EMITTING, TWO_SIDED_EMITTING = 0.0, 1.0, 2.0

kernel = njit(cache=True, nogil=True, fastmath=False)


@k.scalar
def offset_one(px, py, pz, nx, ny, nz, dx, dy, dz, scale):
    """A ray origin moved off the surface along ng, to the side `d` leaves by (no self-hits). The
    distance is relative to `scale`: Embree works in float32, so its errors grow with the coordinates."""
    eps = RAY_OFFSET * max(scale, 1e-30)
    side = eps if dx * nx + dy * ny + dz * nz >= 0 else -eps
    return px + nx * side, py + ny * side, pz + nz * side


@kernel
def offset_origins(position, ng, direction, scale):
    """`_offset` per row; `scale` (N,) is the coordinate magnitude of each point's triangle."""
    out = np.empty_like(position)
    for i in range(len(position)):
        p, n, d = position[i], ng[i], direction[i]
        out[i, 0], out[i, 1], out[i, 2] = offset_one(
            p[0], p[1], p[2], n[0], n[1], n[2], d[0], d[1], d[2], scale[i]
        )
    return out


def triangle_records(ng, coordinate_scale, smooth, material_ids, emission, two_sided_emission):
    """What a hit reads of its triangle, in one 64-byte row per triangle aligned on cache lines (T, 8):
    geometric normal, coordinate magnitude, smooth (1: interpolate the shading normals), material id, and
    whether it emits (`NOT_EMITTING`, ...). In separate arrays these were five cache misses per hit in a
    large scene (cornell_glossy's 164k triangles)."""
    count = len(ng)
    buffer = np.zeros(count * 8 + 8)
    skip = (-buffer.ctypes.data % 64) // 8
    records = buffer[skip : skip + count * 8].reshape(count, 8)
    records[:, NG : NG + 3] = ng
    records[:, SCALE] = coordinate_scale
    records[:, SMOOTH] = smooth
    records[:, MATERIAL] = material_ids
    emits = (np.asarray(emission) != 0).any(axis=1)
    sides = np.where(np.asarray(two_sided_emission, bool), TWO_SIDED_EMITTING, FRONT_EMITTING)
    records[:, EMITS] = np.where(emits, sides, NOT_EMITTING)
    return records


AHEAD = 16  # rows between a prefetch of a hit's triangle and its reads (`surface_points`)


@k.scalar
def _prefetch_triangle(tri, triangles, tri_ns, tri_uv, need_uv):
    """Start loading what `surface_points` reads of triangle `tri`: its record, shading normals and UVs."""
    k.prefetch(triangles, tri * 8)
    k.prefetch(tri_ns, tri * 9)
    k.prefetch(tri_ns, tri * 9 + 8)
    if need_uv:
        k.prefetch(tri_uv, tri * 6)
        k.prefetch(tri_uv, tri * 6 + 5)


@kernel
def surface_points(o, d, t, prim, bu, bv, triangles, tri_ns, tri_uv, need_uv):
    """Per hit: position o + t d, geometric normal, shading normal (interpolated on smooth triangles),
    UV (when `need_uv`, else 0), the coordinate magnitude for ray offsets and the material id; `triangles`
    are the records of `triangle_records`. The triangles of row i + `AHEAD` are prefetched at row i
    (`kernels.prefetch`): in a large scene each hit's reads miss the cache."""
    n = len(o)
    position, ng, ns = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    uv, scale, material = np.zeros((n, 2)), np.empty(n), np.empty(n, np.int64)
    for i in range(n):
        if i + AHEAD < n:
            _prefetch_triangle(prim[i + AHEAD], triangles, tri_ns, tri_uv, need_uv)
        tri = prim[i]
        record = triangles[tri]
        magnitude = record[SCALE]
        for c in range(3):
            position[i, c] = o[i, c] + t[i] * d[i, c]
            ng[i, c] = record[NG + c]
            magnitude = max(magnitude, abs(position[i, c]))
        scale[i] = magnitude
        material[i] = int(record[MATERIAL])
        b1, b2 = np.float64(bu[i]), np.float64(bv[i])
        b0 = 1.0 - b1 - b2
        if record[SMOOTH] != 0:
            sx = b0 * tri_ns[tri, 0, 0] + b1 * tri_ns[tri, 1, 0] + b2 * tri_ns[tri, 2, 0]
            sy = b0 * tri_ns[tri, 0, 1] + b1 * tri_ns[tri, 1, 1] + b2 * tri_ns[tri, 2, 1]
            sz = b0 * tri_ns[tri, 0, 2] + b1 * tri_ns[tri, 1, 2] + b2 * tri_ns[tri, 2, 2]
            length = max(math.sqrt(sx * sx + sy * sy + sz * sz), 1e-300)
            ns[i, 0], ns[i, 1], ns[i, 2] = sx / length, sy / length, sz / length
        else:
            for c in range(3):
                ns[i, c] = ng[i, c]
        if need_uv:
            for c in range(2):
                uv[i, c] = b0 * tri_uv[tri, 0, c] + b1 * tri_uv[tri, 1, c] + b2 * tri_uv[tri, 2, c]
    return position, ng, ns, uv, scale, material


@kernel
def emitted_radiance(prim, d, ng, triangles, emission):
    """Radiance the hit triangles emit back along the rays `d` (front faces, or both sides); whether a
    triangle emits is read from its record (`triangle_records`), so others cost no read of `emission`."""
    n = len(prim)
    out = np.zeros((n, 3))
    for i in range(n):
        tri = prim[i]
        emits = triangles[tri, EMITS]
        if emits == NOT_EMITTING:
            continue
        if emits == TWO_SIDED_EMITTING or -(d[i, 0] * ng[i, 0] + d[i, 1] * ng[i, 1] + d[i, 2] * ng[i, 2]) > 0:
            for c in range(3):
                out[i, c] = emission[tri, c]
    return out


@kernel
def add_emitter_hits(radiance, idx, beta, emitted, prim, t, d, ng, area_pdf, prev_pdf, prev_delta):
    """Add the emission the paths' rays hit, weighted by MIS against light sampling (power heuristic),
    whose pdf of the same point is area_pdf t^2 / |cos| (fully after delta scattering)."""
    for i in range(len(idx)):
        if max(emitted[i, 0], emitted[i, 1], emitted[i, 2]) <= 0:
            continue
        weight = 1.0
        if not prev_delta[i]:
            cos = d[i, 0] * ng[i, 0] + d[i, 1] * ng[i, 1] + d[i, 2] * ng[i, 2]
            pdf_light = area_pdf[prim[i]] * t[i] * t[i] / max(abs(cos), 1e-300)
            weight = k.power_heuristic(prev_pdf[i], pdf_light)
        for c in range(3):
            radiance[idx[i], c] += beta[i, c] * emitted[i, c] * weight


@kernel
def add_escapes(radiance, rows, idx, beta, d, prev_pdf, prev_delta, env_map, env_prob, env_radiance, env_pdf):
    """Add the environment's radiance to the paths `rows` whose rays escaped, weighted by MIS against light
    sampling (power heuristic; fully after delta scattering); returns the weights. The radiance and the
    light-sampling pdf (selection included) come from the lat-long map `env_map` (`env_prob` the map's
    selection probability) or, without one (`NO_MAP`), from `env_radiance`, `env_pdf` per row."""
    weights = np.empty(len(rows))
    if env_map.image.shape[0] > 0:
        env_radiance, env_pdf = lookup_rows(d, rows, env_map)
        for j in range(len(rows)):
            env_pdf[j] *= env_prob
    for j in range(len(rows)):
        i = rows[j]
        r, g, b, pdf = env_radiance[j, 0], env_radiance[j, 1], env_radiance[j, 2], env_pdf[j]
        weight = 1.0 if prev_delta[i] else k.power_heuristic(prev_pdf[i], pdf)
        weights[j] = weight
        p = idx[i]
        radiance[p, 0] += beta[i, 0] * r * weight
        radiance[p, 1] += beta[i, 1] * g * weight
        radiance[p, 2] += beta[i, 2] * b * weight
    return weights


@kernel
def shading_frames(d, ns, two_sided):
    """Frames (s, t, n) around the shading normals, flipped towards the viewer on two-sided surfaces, and
    wo = -d in them."""
    m = len(d)
    fs, ft, nn, wo = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    for i in range(m):
        nx, ny, nz = ns[i, 0], ns[i, 1], ns[i, 2]
        ox, oy, oz = -d[i, 0], -d[i, 1], -d[i, 2]
        if two_sided[i] and ox * nx + oy * ny + oz * nz < 0:
            nx, ny, nz = -nx, -ny, -nz
        s, t = k.frame(nx, ny, nz)
        fs[i, 0], fs[i, 1], fs[i, 2] = s
        ft[i, 0], ft[i, 1], ft[i, 2] = t
        nn[i, 0], nn[i, 1], nn[i, 2] = nx, ny, nz
        wo[i, 0] = ox * s[0] + oy * s[1] + oz * s[2]
        wo[i, 1] = ox * t[0] + oy * t[1] + oz * t[2]
        wo[i, 2] = ox * nx + oy * ny + oz * nz
    return fs, ft, nn, wo


@kernel
def to_local_rows(rows, v, fs, ft, ns):
    """World vectors `v` (one per entry of `rows`) in the frames of `rows`."""
    out = np.empty((len(rows), 3))
    for j in range(len(rows)):
        i = rows[j]
        for c, axis in enumerate((fs, ft, ns)):
            out[j, c] = v[j, 0] * axis[i, 0] + v[j, 1] * axis[i, 1] + v[j, 2] * axis[i, 2]
    return out


@kernel
def shadow_rays(rows, beta, f_cos, bsdf_pdf, lights, position, ng, scale):
    """Next-event estimation at `rows` with the light samples `lights` (direction, distance, radiance,
    pdf, delta; one per row): the MIS-weighted contribution beta f |cos| L w / pdf, and for the rows where
    it is positive (`live`, indices into `rows`) a shadow ray (origin, direction, t_max) stopping short of
    the light. Also returns w / pdf per sample (0 where the pdf is)."""
    direction, distance, light_radiance, light_pdf, light_delta = lights
    m = len(rows)
    light_scale = np.zeros(m)
    contribution = np.empty((m, 3))
    live = np.empty(m, np.int64)
    origin, ray_direction, t_max = np.empty((m, 3)), np.empty((m, 3)), np.empty(m)
    count = 0
    for j in range(m):
        i = rows[j]
        if light_pdf[j] > 0:
            mis = 1.0 if light_delta[j] else k.power_heuristic(light_pdf[j], bsdf_pdf[j])
            light_scale[j] = mis / max(light_pdf[j], 1e-300)
        largest = 0.0
        for c in range(3):
            value = beta[i, c] * f_cos[j, c] * light_radiance[j, c] * light_scale[j]
            contribution[count, c] = value
            largest = max(largest, value)
        if not largest > 0:
            continue
        p, n, dr = position[i], ng[i], direction[j]
        origin[count, 0], origin[count, 1], origin[count, 2] = offset_one(
            p[0], p[1], p[2], n[0], n[1], n[2], dr[0], dr[1], dr[2], scale[i]
        )
        ray_direction[count, 0], ray_direction[count, 1], ray_direction[count, 2] = dr[0], dr[1], dr[2]
        dist = distance[j]
        t_max[count] = dist * (1 - 1e-5) - 2 * RAY_OFFSET * scale[i] if math.isfinite(dist) else math.inf
        live[count] = j
        count += 1
    rays = origin[:count], ray_direction[:count], t_max[:count]
    return live[:count], contribution[:count], *rays, light_scale


@kernel
def add_unblocked(radiance, idx, contribution, blocked):
    """radiance[idx] += contribution where the shadow ray is not blocked."""
    for j in range(len(idx)):
        if not blocked[j]:
            for c in range(3):
                radiance[idx[j], c] += contribution[j, c]


@k.scalar
def _roulette(beta, eta2, u):
    """Russian roulette's factor for a path of throughput `beta` (3,) and uniform u, Mitsuba's rule: survive
    with probability q = min(max(beta) * eta2, 0.95), then scale by 1 / q; 0 for a terminated path.

    eta2 is the product of the squared relative IORs of the path's transmissions (each is the far side's
    index over the near side's). A transmission scales radiance, so beta, by 1/eta^2 (`bsdf` conventions):
    entering glass of index 1.5 leaves beta at 0.44 of the energy the path carries, and leaving it restores
    it. beta * eta2 undoes that scaling, so a path inside glass survives as often as the same path outside
    it; on beta alone it would be killed ~2.25x more often, and the survivors' 1/q weight would add variance
    to everything seen through glass. Any q > 0 keeps the estimator unbiased: q only decides its variance."""
    q = min(max(beta[0], beta[1], beta[2]) * eta2, 0.95)
    return 1.0 / max(q, 1e-300) if u < q else 0.0


@k.scalar
def leave_one(wi, fs, ft, ns, p, nrm, scale, origin, direction):
    """The ray leaving surface point `p` along local direction `wi`, written into `origin` and `direction`:
    the direction is wi in the frame (fs, ft, ns), the origin is offset off the surface to the side it
    leaves by."""
    x, y, z = wi[0], wi[1], wi[2]
    dx = x * fs[0] + y * ft[0] + z * ns[0]
    dy = x * fs[1] + y * ft[1] + z * ns[1]
    dz = x * fs[2] + y * ft[2] + z * ns[2]
    origin[0], origin[1], origin[2] = offset_one(p[0], p[1], p[2], nrm[0], nrm[1], nrm[2], dx, dy, dz, scale)
    direction[0], direction[1], direction[2] = dx, dy, dz


@kernel
def roulette(beta, eta2, u):
    """Russian roulette on whole paths (in place on `beta`); the rows that survive with a throughput > 0."""
    keep = np.empty(len(beta), np.int64)
    count = 0
    for i in range(len(beta)):
        factor = _roulette(beta[i], eta2[i], u[i])
        for c in range(3):
            beta[i, c] *= factor
        if max(beta[i, 0], beta[i, 1], beta[i, 2]) > 0:
            keep[count] = i
            count += 1
    return keep[:count]


@kernel
def next_paths(idx, beta, eta2, sampled, frames, position, ng, scale, u_roulette, use_roulette):
    """The paths that continue from surface points: BSDF samples `sampled` (wi local, weight, pdf, delta,
    eta) turned to world rays offset off the surface, throughput times weight, the paths' eta2 times the
    sample's eta^2 (float64, as beta), Russian roulette where `use_roulette`, and only the paths whose
    throughput stays > 0, compacted. Returns (idx, origin, direction, beta, eta2, pdf, delta) of those."""
    wi, weight, pdf, delta, eta = sampled
    fs, ft, ns = frames
    n = len(idx)
    out_idx, out_o, out_d = np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3))
    out_beta, out_eta2 = np.empty((n, 3)), np.empty(n)
    out_pdf, out_delta = np.empty(n), np.empty(n, np.bool_)
    count = 0
    b = np.empty(3)
    for i in range(n):
        for c in range(3):
            b[c] = beta[i, c] * weight[i, c]
        e2 = eta2[i] * eta[i] * eta[i]
        if use_roulette:
            factor = _roulette(b, e2, u_roulette[i])
            for c in range(3):
                b[c] *= factor
        if not max(b[0], b[1], b[2]) > 0:
            continue
        leave_one(wi[i], fs[i], ft[i], ns[i], position[i], ng[i], scale[i], out_o[count], out_d[count])
        for c in range(3):
            out_beta[count, c] = b[c]
        out_eta2[count] = e2
        out_idx[count], out_pdf[count], out_delta[count] = idx[i], pdf[i], delta[i]
        count += 1
    return (
        out_idx[:count],
        out_o[:count],
        out_d[:count],
        out_beta[:count],
        out_eta2[:count],
        out_pdf[:count],
        out_delta[:count],
    )


@kernel
def vertex_uniforms(u):
    """A surface vertex's 7 uniforms per row (N, 7) as the contiguous arrays its kernels take: light
    selection (N,), light sample (N, 2), BSDF sample (N, 2), lobe choice (N,), roulette (N,). One pass, where
    NumPy copied each strided slice of `u` in its own pass (4% of cornell_box's CPU time)."""
    n = len(u)
    select, light, bsdf = np.empty(n), np.empty((n, 2)), np.empty((n, 2))
    lobe, roulette = np.empty(n), np.empty(n)
    for i in range(n):
        select[i], light[i, 0], light[i, 1] = u[i, 0], u[i, 1], u[i, 2]
        bsdf[i, 0], bsdf[i, 1], lobe[i], roulette[i] = u[i, 3], u[i, 4], u[i, 5], u[i, 6]
    return select, light, bsdf, lobe, roulette


@kernel
def take_paths(rows, paths):
    """The wavefront arrays (idx, o, d, beta, eta2, prev_pdf, prev_delta, t_min, spread) at `rows`, in one
    pass."""
    idx, o, d, beta, eta2, prev_pdf, prev_delta, t_min, spread = paths
    m = len(rows)
    out_o, out_d, out_beta = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
    out_idx, out_eta2, out_pdf, out_delta = (
        np.empty(m, np.int64),
        np.empty(m),
        np.empty(m),
        np.empty(m, np.bool_),
    )
    out_t_min, out_spread = np.empty(m), np.empty(m)
    for j in range(m):
        i = rows[j]
        for c in range(3):
            out_o[j, c], out_d[j, c], out_beta[j, c] = o[i, c], d[i, c], beta[i, c]
        out_idx[j], out_eta2[j], out_pdf[j], out_delta[j] = idx[i], eta2[i], prev_pdf[i], prev_delta[i]
        out_t_min[j], out_spread[j] = t_min[i], spread[i]
    return out_idx, out_o, out_d, out_beta, out_eta2, out_pdf, out_delta, out_t_min, out_spread


@kernel
def rays_leaving(wi, fs, ft, ns, position, ng, scale):
    """Rays leaving surface points along local directions `wi` (one per row): world directions in the frames
    (fs, ft, ns) and origins offset off the surface to the side they leave by."""
    n = len(wi)
    origins, directions = np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        leave_one(wi[i], fs[i], ft[i], ns[i], position[i], ng[i], scale[i], origins[i], directions[i])
    return origins, directions
