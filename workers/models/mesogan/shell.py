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
crossings whose midpoints map inside are the ray's intervals in that prism. The per-point work is compiled
(`prism_kernels`); this module holds the shell's arrays and checks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.models.mesogan import prism_kernels
from workers.scene.format.errors import SceneError

EDGES = ((0, 1), (1, 2), (2, 0))
DEGENERATE = 1e-12  # relative area below which a base triangle has no well-defined prism
INSIDE_TOLERANCE = 1e-7
NEWTON_STEPS = 30  # at most, for the height in the inverse map (each point stops at 1e-13)
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
        self, prism: np.ndarray, p: np.ndarray, iterations: int = NEWTON_STEPS
    ) -> tuple[np.ndarray, np.ndarray]:
        """Barycentrics (N, 3) and height t (N,) of points p (N, 3) in their prisms (module docstring); points
        outside a prism get coordinates outside [0, 1]."""
        return prism_kernels.inverse(
            self.base, self.offsets, _rows(prism), np.ascontiguousarray(p, np.float64), iterations
        )

    def slab_length(self, prism: np.ndarray, start: np.ndarray, b_end: np.ndarray, t_end: np.ndarray):
        """Length in slab heights of the segments from points `start` (N, 3) to the points at (b_end,
        t_end) in prisms `prism`: the chord in the slab's coordinates (the base-triangle position over h,
        and the height), which the prism map stretches sideways by the offset triangle's growth."""
        b_start, t_start = self.inverse(prism, start)
        lateral = np.einsum("ni,nij->nj", b_end - b_start, self.base[prism]) / self.height
        return np.sqrt(np.einsum("ij,ij->i", lateral, lateral) + (t_end - t_start) ** 2)

    def contains(self, b: np.ndarray, t: np.ndarray) -> np.ndarray:
        tol = INSIDE_TOLERANCE
        return (b >= -tol).all(1) & (t >= -tol) & (t <= 1 + tol)

    def uv(self, prism: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.einsum("ni,nij->nj", b, self.uvs[prism])

    def normal(self, prism: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The interpolated unit normal at barycentrics b (the height axis)."""
        n = np.einsum("ni,nij->nj", b, self.normals[prism])
        return n / np.maximum(np.sqrt(np.einsum("ij,ij->i", n, n)), 1e-300)[:, None]

    def frame(self, prism: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tangent (along +u), bitangent (on the side of +v) and normal at barycentrics b: the frame the
        plane's (x, y, height) axes map to, from the base triangle's UV derivatives and the interpolated
        normal. Where the UVs are mirrored (u, v, n left-handed), so is the frame: the plane's y runs along
        +v, and the light and view the decoder reads must be expressed on the same side."""
        n = self.normal(prism, b)
        v, uv = self.base[prism], self.uvs[prism]
        e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
        du1, du2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        det = du1[:, 0] * du2[:, 1] - du1[:, 1] * du2[:, 0]
        det = np.where(np.abs(det) > 1e-300, det, 1e-300)
        dpdu = (e1 * du2[:, 1:] - e2 * du1[:, 1:]) / det[:, None]
        dpdv = (e2 * du1[:, :1] - e1 * du2[:, :1]) / det[:, None]
        tangent = dpdu - (dpdu * n).sum(1, keepdims=True) * n
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
        bitangent = np.cross(n, tangent)
        mirrored = (bitangent * dpdv).sum(1) < 0
        return tangent, np.where(mirrored[:, None], -bitangent, bitangent), n

    # ------------------------------------------------------------------ rays

    def _group_prisms(self) -> None:
        """Prisms in groups of GROUP consecutive along a Morton curve of their centres, with the groups'
        boxes: a two-level hierarchy that `prism_kernels.intervals` tests rays against before single
        prisms."""
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

    def intervals(self, origins, directions, t_min, t_max) -> Intervals:
        """Every segment of every ray (within [t_min, t_max]) inside a prism, sorted by ray then enter: the
        segments between consecutive crossings of a prism's boundary whose midpoints map inside, for the
        prisms whose boxes (and their group's) the ray meets (`prism_kernels.intervals`)."""
        f64 = lambda a: np.ascontiguousarray(a, np.float64)  # noqa: E731
        geometry = (
            self.base, self.top, self.offsets, self.group_lo, self.group_hi, self.order, self.lo, self.hi
        )  # fmt: skip
        ray, prism, enter, leave = prism_kernels.intervals(
            f64(origins), f64(directions), f64(t_min), f64(t_max), geometry, GROUP, NEWTON_STEPS,
            INSIDE_TOLERANCE,
        )  # fmt: skip
        order = np.lexsort((enter, ray))
        return Intervals(ray[order], prism[order], enter[order], leave[order])


def _rows(prism: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(prism, np.int64)
