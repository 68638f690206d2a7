"""What the path tracer asks of geometry: closest hits and occlusion, for batches of rays.

Embree (`workers.render.embree`) answers over triangles; a model kind may answer part of a scene itself
(a network that predicts hits, for instance) by implementing `Intersector` in its own package and handing
it to `PathTracer`. Hits always name a triangle of the compiled scene, which gives the object, instance
and coordinate scale of the hit; an intersector that predicts the surface as well sets a
`SurfaceOverride` on those rows.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Protocol

import numpy as np


@dataclass
class SurfaceOverride:
    """Surfaces predicted by an intersector in place of the hit triangle's, on the rows of `where`.

    There `normal` is both the geometric and the shading normal, and `material` and `albedo` replace the
    triangle's material and base colour (roughness and index of refraction stay the material's).
    """

    where: np.ndarray  # (N,) bool
    normal: np.ndarray  # (N, 3) unit world-space normal
    material: np.ndarray  # (N,) scene material id
    albedo: np.ndarray  # (N, 3) base colour

    def take(self, rows: np.ndarray) -> SurfaceOverride:
        return SurfaceOverride(*(getattr(self, f.name)[rows] for f in fields(self)))


@dataclass
class Hits:
    """Closest hits of a batch of rays; `prim` is -1 where the ray escaped. Intersectors that only
    intersect triangles leave `surface` None, which costs the path tracer nothing."""

    prim: np.ndarray  # (N,) int32 triangle index into the compiled scene
    t: np.ndarray  # (N,) float64 distance along the (unit) direction
    u: np.ndarray  # (N,) barycentric weight of vertex 1
    v: np.ndarray  # (N,) barycentric weight of vertex 2
    surface: SurfaceOverride | None = None

    @property
    def found(self) -> np.ndarray:
        return self.prim >= 0

    @staticmethod
    def misses(n: int) -> Hits:
        """n rays that hit nothing."""
        return Hits(np.full(n, -1, np.int32), np.full(n, np.inf), np.zeros(n), np.zeros(n))

    def interpolate(self, corners: np.ndarray) -> np.ndarray:
        """(N, C) float64 values at the hits of per-corner attributes `corners` (N, 3, C) of the hit
        triangles: (1 - u - v) c0 + u c1 + v c2."""
        b1, b2 = self.u.astype(np.float64)[:, None], self.v.astype(np.float64)[:, None]
        corners = corners.astype(np.float64)
        return (1.0 - b1 - b2) * corners[:, 0] + b1 * corners[:, 1] + b2 * corners[:, 2]

    def take(self, rows: np.ndarray) -> Hits:
        """The hits of `rows` only, overrides included."""
        surface = None if self.surface is None else self.surface.take(rows)
        return Hits(self.prim[rows], self.t[rows], self.u[rows], self.v[rows], surface)


class Intersector(Protocol):
    """Closest-hit and occlusion queries; rays are world-space with unit directions."""

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits: ...

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """True where something lies on the segment [0, t_max) of each ray."""
        ...
