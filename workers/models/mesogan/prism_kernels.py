"""Compiled per-point kernels of the shell's geometry (`shell.Shell`): the inverse prism map, the ray's
crossings of a prism's boundary and the broad phase of ray against prism boxes.

The vectorised NumPy forms of these ran a few dozen array passes per call and were most of the shell's
render time (a profile of the furred ball: 65% geometry, 10% network). Each kernel is the same
mathematics per point in registers:

- `inverse`: the cubic det[v1(t) - v0(t), v2(t) - v0(t), p - v0(t)] = 0 in closed-form coefficients
  (cross products of the base edges and the offset edges), Newton from the flat-prism guess per point,
  then the barycentrics in the offset triangle at t.
- `crossings`: Moller-Trumbore against the bottom and top triangles; each side patch, projected onto two
  planes containing the ray (Duff et al. 2017's frame), is a quadratic in the edge parameter.
- `intervals`: slab tests against the boxes of groups of prisms, then the boxes of the prisms of the
  groups met, then the crossings; the output grows by doubling (one pass, even for rays that cross many
  prisms).
"""

from __future__ import annotations

import numpy as np

from workers.render.jit import njit

TINY = 1e-300
NEWTON_TOLERANCE = 1e-13


@njit(cache=True)
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(cache=True)
def _dot(u, w):
    return u[0] * w[0] + u[1] * w[1] + u[2] * w[2]


@njit(cache=True)
def _safe(x):
    return x if abs(x) > TINY else TINY


@njit(cache=True)
def _inverse_point(base, offsets, j, px, py, pz, iterations):
    """Barycentrics and height of the point (px, py, pz) in prism j (`inverse`)."""
    v0, v1, v2 = base[j, 0], base[j, 1], base[j, 2]
    o0, o1, o2 = offsets[j, 0], offsets[j, 1], offsets[j, 2]
    e1 = (v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2])
    e2 = (v2[0] - v0[0], v2[1] - v0[1], v2[2] - v0[2])
    d1 = (o1[0] - o0[0], o1[1] - o0[1], o1[2] - o0[2])
    d2 = (o2[0] - o0[0], o2[1] - o0[1], o2[2] - o0[2])
    q = (px - v0[0], py - v0[1], pz - v0[2])
    a = _cross(e1[0], e1[1], e1[2], e2[0], e2[1], e2[2])
    b1 = _cross(e1[0], e1[1], e1[2], d2[0], d2[1], d2[2])
    b2 = _cross(d1[0], d1[1], d1[2], e2[0], e2[1], e2[2])
    b = (b1[0] + b2[0], b1[1] + b2[1], b1[2] + b2[2])
    c = _cross(d1[0], d1[1], d1[2], d2[0], d2[1], d2[2])
    # det(t) = (a + b t + c t^2) . (q - t o0)
    c0 = _dot(a, q)
    c1 = _dot(b, q) - _dot(a, o0)
    c2 = _dot(c, q) - _dot(b, o0)
    c3 = -_dot(c, o0)
    mean_offset = (
        (o0[0] + o1[0] + o2[0]) / 3.0,
        (o0[1] + o1[1] + o2[1]) / 3.0,
        (o0[2] + o1[2] + o2[2]) / 3.0,
    )
    t = _dot(q, a) / _safe(_dot(mean_offset, a))
    for _ in range(iterations):
        f = c0 + t * (c1 + t * (c2 + t * c3))
        df = c1 + t * (2.0 * c2 + 3.0 * c3 * t)
        step = min(max(f / _safe(df), -0.5), 0.5)
        t -= step
        if abs(step) < NEWTON_TOLERANCE:
            break
    f1 = (e1[0] + t * d1[0], e1[1] + t * d1[1], e1[2] + t * d1[2])
    f2 = (e2[0] + t * d2[0], e2[1] + t * d2[1], e2[2] + t * d2[2])
    r = (q[0] - t * o0[0], q[1] - t * o0[1], q[2] - t * o0[2])
    d11, d12, d22 = _dot(f1, f1), _dot(f1, f2), _dot(f2, f2)
    r1, r2 = _dot(r, f1), _dot(r, f2)
    den = d11 * d22 - d12 * d12
    w1 = (d22 * r1 - d12 * r2) / den
    w2 = (d11 * r2 - d12 * r1) / den
    return 1.0 - w1 - w2, w1, w2, t


@njit(cache=True)
def inverse(base, offsets, prism, p, iterations):
    """Barycentrics (N, 3) and heights (N,) of points p (N, 3) in prisms `prism` (N,) of base triangles
    `base` (P, 3, 3) and vertex offsets `offsets` (P, 3, 3) (h times the unit normals)."""
    n = len(prism)
    bary = np.empty((n, 3))
    height = np.empty(n)
    for k in range(n):
        bary[k, 0], bary[k, 1], bary[k, 2], height[k] = _inverse_point(
            base, offsets, prism[k], p[k, 0], p[k, 1], p[k, 2], iterations
        )
    return bary, height


@njit(cache=True)
def _triangle(ox, oy, oz, dx, dy, dz, tri):
    """Moller-Trumbore distance to triangle `tri` (3, 3), or inf."""
    e1x, e1y, e1z = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    e2x, e2y, e2z = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    px, py, pz = _cross(dx, dy, dz, e2x, e2y, e2z)
    det = e1x * px + e1y * py + e1z * pz
    if abs(det) <= TINY:
        return np.inf
    tx, ty, tz = ox - tri[0, 0], oy - tri[0, 1], oz - tri[0, 2]
    u = (tx * px + ty * py + tz * pz) / det
    qx, qy, qz = _cross(tx, ty, tz, e1x, e1y, e1z)
    v = (dx * qx + dy * qy + dz * qz) / det
    if u < 0 or v < 0 or u + v > 1:
        return np.inf
    return (e2x * qx + e2y * qy + e2z * qz) / det


@njit(cache=True)
def _patch_along(q00, q10, q01, q11, ox, oy, oz, u):
    """The bilinear patch minus the origin, projected on u: a + b s + c t + e s t."""
    a = (q00[0] - ox) * u[0] + (q00[1] - oy) * u[1] + (q00[2] - oz) * u[2]
    b = (q10[0] - q00[0]) * u[0] + (q10[1] - q00[1]) * u[1] + (q10[2] - q00[2]) * u[2]
    c = (q01[0] - q00[0]) * u[0] + (q01[1] - q00[1]) * u[1] + (q01[2] - q00[2]) * u[2]
    e = (
        (q11[0] - q10[0] - q01[0] + q00[0]) * u[0]
        + (q11[1] - q10[1] - q01[1] + q00[1]) * u[1]
        + (q11[2] - q10[2] - q01[2] + q00[2]) * u[2]
    )
    return a, b, c, e


@njit(cache=True)
def _crossings(out, o, d, base, top, j):
    """Distances `out` (8,) where the ray (o, d) crosses prism j's boundary (inf where it does not): the
    bottom and top triangles and two per side patch q(s, t) = lerp(lerp(b_i, b_j, s), lerp(t_i, t_j, s),
    t)."""
    out[:] = np.inf
    ox, oy, oz = o[0], o[1], o[2]
    dx, dy, dz = d[0], d[1], d[2]
    out[0] = _triangle(ox, oy, oz, dx, dy, dz, base[j])
    out[1] = _triangle(ox, oy, oz, dx, dy, dz, top[j])
    # Two unit vectors perpendicular to d (Duff et al. 2017).
    sign = 1.0 if dz >= 0 else -1.0
    a = -1.0 / (sign + dz)
    bb = dx * dy * a
    u1 = (1.0 + sign * dx * dx * a, sign * bb, -sign * dx)
    u2 = (bb, sign + dy * dy * a, -dy)
    for edge in range(3):
        i0, i1 = edge, (edge + 1) % 3
        q00, q10, q01, q11 = base[j, i0], base[j, i1], top[j, i0], top[j, i1]
        a1, b1, c1, e1 = _patch_along(q00, q10, q01, q11, ox, oy, oz, u1)
        a2, b2, c2, e2 = _patch_along(q00, q10, q01, q11, ox, oy, oz, u2)
        # t = -(a1 + b1 s) / (c1 + e1 s); (a2 + b2 s)(c1 + e1 s) - (c2 + e2 s)(a1 + b1 s) = 0
        qa = b2 * e1 - e2 * b1
        qb = a2 * e1 + b2 * c1 - c2 * b1 - e2 * a1
        qc = a2 * c1 - c2 * a1
        roots = (np.inf, np.inf)
        if abs(qa) <= 1e-12 * (abs(qb) + abs(qc) + TINY):
            roots = (-qc / _safe(qb), np.inf)
        else:
            disc = qb * qb - 4 * qa * qc
            if disc >= 0:
                root = np.sqrt(disc)
                qq = -0.5 * (qb + (root if qb >= 0 else -root))
                roots = (qq / qa, qc / _safe(qq))
        for r in range(2):
            s = roots[r]
            if not (s >= 0 and s <= 1):
                continue
            den1, den2 = c1 + e1 * s, c2 + e2 * s
            num, den = (a1 + b1 * s, den1) if abs(den1) >= abs(den2) else (a2 + b2 * s, den2)
            t = -num / _safe(den)
            if not (t >= 0 and t <= 1):
                continue
            dist = 0.0
            for x in range(3):
                point = (1 - t) * ((1 - s) * q00[x] + s * q10[x]) + t * ((1 - s) * q01[x] + s * q11[x])
                dist += (point - o[x]) * d[x]
            out[2 + 2 * edge + r] = dist


@njit(cache=True)
def _box_met(o, inv, t_min, t_max, lo, hi):
    near, far = -np.inf, np.inf
    for x in range(3):
        a = (lo[x] - o[x]) * inv[x]
        b = (hi[x] - o[x]) * inv[x]
        near = max(near, min(a, b))
        far = min(far, max(a, b))
    return near <= far and far >= t_min and near <= t_max


@njit(cache=True)
def _in_box(x, y, z, lo, hi, margin):
    return (
        lo[0] - margin <= x <= hi[0] + margin
        and lo[1] - margin <= y <= hi[1] + margin
        and lo[2] - margin <= z <= hi[2] + margin
    )


@njit(cache=True)
def _intervals(origins, directions, t_min, t_max, shell, group, iterations, tolerance):
    base, top, offsets, group_lo, group_hi, order, lo, hi = shell
    capacity = 4 * len(origins) + 64
    out_ray, out_prism, out_t = (
        np.empty(capacity, np.int64),
        np.empty(capacity, np.int64),
        np.empty((capacity, 2)),
    )
    count = 0
    all_lo, all_hi = np.empty(3), np.empty(3)
    for x in range(3):
        all_lo[x], all_hi[x] = group_lo[:, x].min(), group_hi[:, x].max()
    cross = np.empty(8)
    bounds = np.empty(10)  # t0, up to 8 crossings, t1
    for r in range(len(origins)):
        o, d = origins[r], directions[r]
        inv = np.empty(3)
        for x in range(3):
            inv[x] = 1.0 / (d[x] if abs(d[x]) > TINY else TINY)
        t0, t1 = t_min[r], t_max[r]
        if not _box_met(o, inv, t0, t1, all_lo, all_hi):
            continue
        for g in range(len(group_lo)):
            if not _box_met(o, inv, t0, t1, group_lo[g], group_hi[g]):
                continue
            for slot in range(g * group, min((g + 1) * group, len(order))):
                j = order[slot]
                if not _box_met(o, inv, t0, t1, lo[j], hi[j]):
                    continue
                _crossings(cross, o, d, base, top, j)
                # [t0, the crossings within (t0, t1) in order (insertion sort: usually two), t1]
                bounds[0] = t0
                k = 0
                for m in range(8):
                    c = cross[m]
                    if c > t0 and c < t1:
                        i = k
                        while i >= 1 and bounds[i] > c:
                            bounds[i + 1] = bounds[i]
                            i -= 1
                        bounds[i + 1] = c
                        k += 1
                bounds[k + 1] = t1
                margin = 10 * tolerance * max(hi[j, 0] - lo[j, 0], hi[j, 1] - lo[j, 1], hi[j, 2] - lo[j, 2])
                for m in range(k + 1):
                    enter, leave = bounds[m], bounds[m + 1]
                    if not (leave > enter and leave < np.inf):
                        continue
                    mid = 0.5 * (enter + leave)
                    px, py, pz = o[0] + mid * d[0], o[1] + mid * d[1], o[2] + mid * d[2]
                    if not _in_box(px, py, pz, lo[j], hi[j], margin):
                        continue  # the prism lies in its corners' box (its side patches in their hulls)
                    b0, b1, b2, h = _inverse_point(base, offsets, j, px, py, pz, iterations)
                    if min(b0, b1, b2) < -tolerance or h < -tolerance or h > 1 + tolerance:
                        continue
                    if count == capacity:  # room for twice as many rows
                        capacity *= 2
                        grown_ray, grown_prism = np.empty(capacity, np.int64), np.empty(capacity, np.int64)
                        grown_t = np.empty((capacity, 2))
                        grown_ray[:count], grown_prism[:count], grown_t[:count] = out_ray, out_prism, out_t
                        out_ray, out_prism, out_t = grown_ray, grown_prism, grown_t
                    out_ray[count] = r
                    out_prism[count] = j
                    out_t[count, 0] = enter
                    out_t[count, 1] = leave
                    count += 1
    return out_ray[:count], out_prism[:count], out_t[:count, 0].copy(), out_t[:count, 1].copy()


def intervals(origins, directions, t_min, t_max, shell, group, iterations, tolerance):
    """(ray, prism, enter, leave) of every segment of the rays (within [t_min, t_max]) inside a prism, in
    ray order: the segments between consecutive boundary crossings whose midpoints map inside, for the
    prisms whose boxes (and their group's box) the ray meets. `shell` is (base, top, offsets, group_lo,
    group_hi, order, lo, hi) (`shell.Shell`)."""
    return _intervals(origins, directions, t_min, t_max, shell, group, iterations, tolerance)
