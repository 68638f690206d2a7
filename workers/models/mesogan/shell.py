"""Shell mapping (Porumbescu et al. 2005; Diolatzis 2022, Sec. 6.2.8): each base triangle extruded along
its vertex normals by the shell height h into a prism, with the exact prism map

    p(b, t) = sum_i b_i (v_i + t h n_i),   b barycentric, t in [0, 1] the height in the shell.

Its inverse solves the cubic det[v1(t) - v0(t), v2(t) - v0(t), p - v0(t)] = 0 for t (p lies in the
plane of the offset triangle at height t), then the barycentrics in that triangle. A prism's side faces
are bilinear patches that depend only on their edge's two vertices and normals, so neighbouring prisms
share them exactly and map their points to the same (edge position, height): the texture is continuous
across triangles wherever the UVs are.

Rays meet prisms at the top and bottom triangles (Moller-Trumbore) and at the side patches (a
quadratic after projecting onto two planes containing the ray); the segments between consecutive
crossings whose midpoints map inside are the ray's intervals in that prism.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.scene.errors import SceneError
from workers.scene.procedural import orthonormal_frames

EDGES = ((0, 1), (1, 2), (2, 0))
DEGENERATE = 1e-12  # relative area below which a base triangle has no well-defined prism
INSIDE_TOLERANCE = 1e-7
GROUP = 16  # prisms per box of the hierarchy's upper level


@dataclass
class Intervals:
    """Segments of rays inside prisms: ray row, prism, and [enter, leave) along the ray."""

    ray: np.ndarray
    prism: np.ndarray
    enter: np.ndarray
    leave: np.ndarray


class Shell:
    """Prisms over base triangles `positions` (P, 3, 3) with unit vertex `normals` (P, 3, 3), UVs
    (P, 3, 2) and height `height`. Raises `SceneError` on degenerate triangles or a shell so thick that a
    prism folds over (the offset triangle flips somewhere in t in [0, 1])."""

    def __init__(self, positions, normals, uvs, height: float, field: str = "shell_height") -> None:
        self.base = np.asarray(positions, np.float64)
        normals = np.asarray(normals, np.float64)
        self.normals = normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)
        self.uvs = np.asarray(uvs, np.float64)
        self.height = float(height)
        self.offsets = self.height * self.normals
        self.top = self.base + self.offsets
        corners = np.concatenate([self.base, self.top], 1)
        self.lo, self.hi = corners.min(1), corners.max(1)
        self._check(field)
        self._group_prisms()

    def __len__(self) -> int:
        return len(self.base)

    def _check(self, field: str) -> None:
        v, o = self.base, self.offsets
        face = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        scale = np.maximum(np.abs(v).max((1, 2)), self.height) ** 2
        area = np.linalg.norm(face, axis=1)
        if (bad := np.flatnonzero(area <= DEGENERATE * scale)).size:
            raise SceneError(
                field, f"triangle {int(bad[0])} of the covered surfaces is degenerate ({bad.size} in all)"
            )
        unit = face / area[:, None]
        # The offset triangle's normal is quadratic in t: n(t) = c0 + c1 t + c2 t^2; it must keep facing
        # along the base normal over t in [0, 1] (checked at the ends, the middle and the extremum).
        e1, e2, d1, d2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], o[:, 1] - o[:, 0], o[:, 2] - o[:, 0]
        c0 = (face * unit).sum(1)
        c1 = ((np.cross(e1, d2) + np.cross(d1, e2)) * unit).sum(1)
        c2 = (np.cross(d1, d2) * unit).sum(1)
        ts = [np.zeros_like(c0), np.full_like(c0, 0.5), np.ones_like(c0)]
        ts.append(np.clip(-c1 / np.where(np.abs(c2) > 1e-300, 2 * c2, np.inf), 0, 1))
        worst = np.min([c0 + c1 * t + c2 * t * t for t in ts], axis=0)
        facing = (self.normals * unit[:, None]).sum(-1).min(1)
        if (bad := np.flatnonzero((worst <= 0.05 * c0) | (facing <= 0.05))).size:
            raise SceneError(
                field,
                f"a shell of height {self.height:g} folds over at triangle {int(bad[0])} "
                f"({bad.size} in all): "
                "it is thicker than the surface's local radius of curvature, or a vertex normal leans past "
                "the face; lower the shell height or refine the mesh",
            )

    # ------------------------------------------------------------------ the map and its inverse

    def point(self, prism: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
        """p(b, t) in prism `prism` (N,), barycentrics b (N, 3), heights t (N,)."""
        corners = self.base[prism] + t[:, None, None] * self.offsets[prism]
        return (b[:, :, None] * corners).sum(1)

    def inverse(
        self, prism: np.ndarray, p: np.ndarray, iterations: int = 30
    ) -> tuple[np.ndarray, np.ndarray]:
        """Barycentrics (N, 3) and height t (N,) of points p (N, 3) in their prisms (module docstring); points
        outside a prism get coordinates outside [0, 1]."""
        v, o = self.base[prism], self.offsets[prism]

        def det(t: np.ndarray) -> np.ndarray:
            c = v + t[:, None, None] * o
            return np.einsum("ij,ij->i", np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), p - c[:, 0])

        # Exact cubic coefficients from four samples (Lagrange on t = 0, 1/3, 2/3, 1).
        samples = np.stack([det(np.full(len(p), k / 3.0)) for k in range(4)], 1)
        nodes = np.array([0.0, 1 / 3, 2 / 3, 1.0])
        coefficients = samples @ np.linalg.inv(np.vander(nodes, 4, increasing=True)).T  # (N, 4): a0..a3
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        rise = np.einsum("ij,ij->i", o.mean(1), normal)
        t = np.einsum("ij,ij->i", p - v[:, 0], normal) / np.where(np.abs(rise) > 1e-300, rise, 1e-300)
        a0, a1, a2, a3 = coefficients.T
        for _ in range(iterations):
            f = a0 + t * (a1 + t * (a2 + t * a3))
            df = a1 + t * (2 * a2 + 3 * a3 * t)
            step = f / np.where(np.abs(df) > 1e-300, df, 1e-300)
            t = t - np.clip(step, -0.5, 0.5)
            if np.all(np.abs(step) < 1e-13):
                break
        c = v + t[:, None, None] * o
        e1, e2, q = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0], p - c[:, 0]
        d11, d12, d22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        q1, q2 = (q * e1).sum(1), (q * e2).sum(1)
        denominator = d11 * d22 - d12 * d12
        b1 = (d22 * q1 - d12 * q2) / denominator
        b2 = (d11 * q2 - d12 * q1) / denominator
        return np.stack([1 - b1 - b2, b1, b2], 1), t

    def contains(self, b: np.ndarray, t: np.ndarray) -> np.ndarray:
        tol = INSIDE_TOLERANCE
        return (b >= -tol).all(1) & (t >= -tol) & (t <= 1 + tol)

    def uv(self, prism: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (b[:, :, None] * self.uvs[prism]).sum(1)

    def frame(self, prism: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tangent (along +u), bitangent and normal at barycentrics b: the frame the plane's (x, y, height)
        axes map to, from the base triangle's UV derivatives and the interpolated normal."""
        n = (b[:, :, None] * self.normals[prism]).sum(1)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        v, uv = self.base[prism], self.uvs[prism]
        e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
        du1, du2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = du1[:, 0] * du2[:, 1] - du1[:, 1] * du2[:, 0]
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        dpdu = (e1 * du2[:, 1:] - e2 * du1[:, 1:]) / det[:, None]
        tangent = dpdu - (dpdu * n).sum(1, keepdims=True) * n
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        return tangent, np.cross(n, tangent), n

    # ------------------------------------------------------------------ rays

    def _group_prisms(self) -> None:
        """Prisms in groups of GROUP consecutive along a Morton curve of their centres, with the groups'
        boxes: a two-level hierarchy that `candidates` tests rays against before single prisms."""
        centre = 0.5 * (self.lo + self.hi)
        span = np.maximum(centre.max(0) - centre.min(0), 1e-300)
        cells = np.clip(((centre - centre.min(0)) / span * 1023).astype(np.int64), 0, 1023)
        code = np.zeros(len(self), np.int64)
        for bit in range(10):
            for axis in range(3):
                code |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
        self.order = np.argsort(code, kind="stable")
        starts = np.arange(0, len(self), GROUP)
        self.group_lo = np.minimum.reduceat(self.lo[self.order], starts)
        self.group_hi = np.maximum.reduceat(self.hi[self.order], starts)

    def candidates(self, origins, directions, t_min, t_max) -> tuple[np.ndarray, np.ndarray]:
        """(ray, prism) pairs whose prism's box the ray segment [t_min, t_max] meets (slab tests against
        the groups' boxes, then against the prisms of the groups met)."""
        inv = 1.0 / np.where(np.abs(directions) > 1e-300, directions, 1e-300)
        ray, group = _boxes_met(origins, inv, t_min, t_max, self.group_lo, self.group_hi)
        ray = np.repeat(ray, GROUP)
        slot = (group[:, None] * GROUP + np.arange(GROUP)[None]).ravel()
        inside = slot < len(self)
        ray, prism = ray[inside], self.order[slot[inside]]
        a, b = (self.lo[prism] - origins[ray]) * inv[ray], (self.hi[prism] - origins[ray]) * inv[ray]
        near, far = np.minimum(a, b).max(-1), np.maximum(a, b).min(-1)
        met = (near <= far) & (far >= t_min[ray]) & (near <= t_max[ray])
        return ray[met], prism[met]

    def crossings(self, o: np.ndarray, d: np.ndarray, prism: np.ndarray) -> np.ndarray:
        """Distances (N, 8) where rays cross the boundary of their prisms (inf where they do not): the
        bottom and top triangles and two per side patch."""
        out = np.full((len(o), 8), np.inf)
        out[:, 0] = _triangle(o, d, self.base[prism])
        out[:, 1] = _triangle(o, d, self.top[prism])
        for k, (i, j) in enumerate(EDGES):
            out[:, 2 + 2 * k : 4 + 2 * k] = _bilinear(
                o, d, self.base[prism, i], self.base[prism, j], self.top[prism, i], self.top[prism, j]
            )
        return out

    def intervals(self, origins, directions, t_min, t_max) -> Intervals:
        """Every segment of every ray (within [t_min, t_max]) inside a prism, sorted by ray then enter."""
        ray, prism = self.candidates(origins, directions, t_min, t_max)
        if len(ray) == 0:
            empty = np.zeros(0, np.int64)
            return Intervals(empty, empty, np.zeros(0), np.zeros(0))
        o, d = origins[ray], directions[ray]
        lo, hi = t_min[ray], t_max[ray]
        cross = self.crossings(o, d, prism)
        cross = np.where((cross > lo[:, None]) & (cross < hi[:, None]), cross, np.inf)
        bounds = np.sort(np.concatenate([lo[:, None], cross, np.full((len(ray), 1), np.inf)], 1), axis=1)
        bounds = np.minimum(bounds, hi[:, None])
        enter, leave = bounds[:, :-1], bounds[:, 1:]
        valid = (leave > enter) & np.isfinite(leave)
        rows, cols = np.nonzero(valid)
        a, b = enter[rows, cols], leave[rows, cols]
        mid = 0.5 * (a + b)
        bary, t = self.inverse(prism[rows], o[rows] + mid[:, None] * d[rows])
        inside = self.contains(bary, t)
        rows, a, b = rows[inside], a[inside], b[inside]
        order = np.lexsort((a, ray[rows]))
        rows, a, b = rows[order], a[order], b[order]
        return Intervals(ray[rows], prism[rows], a, b)


def _boxes_met(origins, inv, t_min, t_max, lo, hi, chunk: int = 1 << 21) -> tuple[np.ndarray, np.ndarray]:
    """(ray, box) pairs of rays (inverse directions `inv`) meeting boxes [lo, hi] within [t_min, t_max]."""
    rays, boxes = [], []
    per = max(1, chunk // max(len(lo), 1))
    for start in range(0, len(origins), per):
        o, i = origins[start : start + per, None], inv[start : start + per, None]
        a, b = (lo[None] - o) * i, (hi[None] - o) * i
        near, far = np.minimum(a, b).max(-1), np.maximum(a, b).min(-1)
        lo_t, hi_t = t_min[start : start + per, None], t_max[start : start + per, None]
        r, g = np.nonzero((near <= far) & (far >= lo_t) & (near <= hi_t))
        rays.append(r + start)
        boxes.append(g)
    return np.concatenate(rays), np.concatenate(boxes)


def _triangle(o: np.ndarray, d: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Moller-Trumbore: distance to triangles (N, 3, 3) or inf."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    pv = np.cross(d, e2)
    det = (e1 * pv).sum(1)
    safe = np.where(np.abs(det) > 1e-300, det, 1e-300)
    tv = o - tri[:, 0]
    u = (tv * pv).sum(1) / safe
    qv = np.cross(tv, e1)
    v = (d * qv).sum(1) / safe
    t = (e2 * qv).sum(1) / safe
    hit = (np.abs(det) > 1e-300) & (u >= 0) & (v >= 0) & (u + v <= 1)
    return np.where(hit, t, np.inf)


def _bilinear(o, d, q00, q10, q01, q11) -> np.ndarray:
    """Distances (N, 2) to the bilinear patches q(s, t) = lerp(lerp(q00, q10, s), lerp(q01, q11, s), t).

    Projected on two planes containing each ray, q(s, t) - o = 0 is two bilinear equations in (s, t);
    eliminating t leaves a quadratic in s."""
    u1, u2 = orthonormal_frames(d)

    def coefficients(u):
        a = ((q00 - o) * u).sum(1)
        b = ((q10 - q00) * u).sum(1)
        c = ((q01 - q00) * u).sum(1)
        e = ((q11 - q10 - q01 + q00) * u).sum(1)
        return a, b, c, e  # a + b s + c t + e s t

    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        return _bilinear_roots(o, d, q00, q10, q01, q11, coefficients(u1), coefficients(u2))


def _bilinear_roots(o, d, q00, q10, q01, q11, first, second) -> np.ndarray:
    a1, b1, c1, e1 = first
    a2, b2, c2, e2 = second
    # t = -(a1 + b1 s) / (c1 + e1 s); (a2 + b2 s)(c1 + e1 s) - (c2 + e2 s)(a1 + b1 s) = 0
    qa = b2 * e1 - e2 * b1
    qb = a2 * e1 + b2 * c1 - c2 * b1 - e2 * a1
    qc = a2 * c1 - c2 * a1
    out = np.full((len(o), 2), np.inf)
    linear = np.abs(qa) <= 1e-12 * (np.abs(qb) + np.abs(qc) + 1e-300)
    disc = qb * qb - 4 * qa * qc
    root = np.sqrt(np.maximum(disc, 0.0))
    # Numerically stable roots: q = -(b + sign(b) sqrt(disc)) / 2; s = q / a and c / q.
    qq = -0.5 * (qb + np.where(qb >= 0, root, -root))
    s_a = np.where(linear, -qc / np.where(np.abs(qb) > 1e-300, qb, 1e-300), qq / np.where(linear, 1.0, qa))
    s_b = np.where(linear, np.inf, qc / np.where(np.abs(qq) > 1e-300, qq, 1e-300))
    for k, s in enumerate((s_a, s_b)):
        ok = (disc >= 0) & (s >= 0) & (s <= 1)
        den1, den2 = c1 + e1 * s, c2 + e2 * s
        use1 = np.abs(den1) >= np.abs(den2)
        num = np.where(use1, a1 + b1 * s, a2 + b2 * s)
        den = np.where(use1, den1, den2)
        t = -num / np.where(np.abs(den) > 1e-300, den, 1e-300)
        ok &= (t >= 0) & (t <= 1)
        s3, t3 = np.where(ok, s, 0.0)[:, None], np.where(ok, t, 0.0)[:, None]
        point = (1 - t3) * ((1 - s3) * q00 + s3 * q10) + t3 * ((1 - s3) * q01 + s3 * q11)
        out[:, k] = np.where(ok, ((point - o) * d).sum(1), np.inf)
    return out
