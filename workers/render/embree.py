"""Closest-hit and occlusion queries through Embree (embreex); each call releases the GIL."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh


@dataclass
class Hits:
    """Closest hits of a batch of rays; `prim` is -1 where the ray escaped.

    Intersectors that answer some hits without triangles (neural objects) set `neural` and, on those
    rows, the surface they predicted: `prim` then names a triangle of the hit instance (for its object,
    instance and coordinate scale), `normal` is the shading and geometric normal, and `material` and
    `albedo` replace the triangle's. Embree's own hits leave these None and cost nothing extra.
    """

    prim: np.ndarray  # (N,) int32 triangle index into the compiled scene
    t: np.ndarray  # (N,) float64 distance along the (unit) direction
    u: np.ndarray  # (N,) barycentric weight of vertex 1
    v: np.ndarray  # (N,) barycentric weight of vertex 2
    neural: np.ndarray | None = None  # (N,) bool: the surface below comes from a model
    normal: np.ndarray | None = None  # (N, 3) unit world-space normal where `neural`
    material: np.ndarray | None = None  # (N,) scene material id where `neural`
    albedo: np.ndarray | None = None  # (N, 3) base colour where `neural`

    @property
    def found(self) -> np.ndarray:
        return self.prim >= 0

    def take(self, rows: np.ndarray) -> Hits:
        """The hits of `rows` only, overrides included."""
        if self.neural is None:
            return Hits(self.prim[rows], self.t[rows], self.u[rows], self.v[rows])
        return Hits(
            self.prim[rows], self.t[rows], self.u[rows], self.v[rows],
            self.neural[rows], self.normal[rows], self.material[rows], self.albedo[rows],
        )  # fmt: skip


class RayScene:
    """One Embree scene over world-space triangles (T, 3, 3)."""

    def __init__(self, positions: np.ndarray, robust: bool = True):
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, np.ascontiguousarray(positions, dtype=np.float32))
        # Embree builds its BVH lazily on the first query: build it now, once, not inside a worker thread.
        self.intersect(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        if len(origins) == 0:
            empty = np.zeros(0)
            return Hits(np.zeros(0, np.int32), empty, empty, empty)
        out = self._scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            output=1,
        )
        return Hits(out["primID"], out["tfar"].astype(np.float64), out["u"], out["v"])

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        """True where something lies on the segment [0, t_max) of each ray."""
        if len(origins) == 0:
            return np.zeros(0, bool)
        out = self._scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            dists=np.ascontiguousarray(np.minimum(t_max, 3.0e38), dtype=np.float32),
            query="OCCLUDED",
        )
        return out != -1


class SubsetRayScene:
    """Embree over some of a scene's triangles (`triangle_ids` into its positions), answering with the
    scene's own triangle indices, so a `PathTracer` over the whole scene can trace just these. An empty
    subset is answered without Embree: every ray escapes."""

    def __init__(self, positions: np.ndarray, triangle_ids: np.ndarray, robust: bool = True):
        self.triangle_ids = np.asarray(triangle_ids, np.int64)
        self._scene = RayScene(positions[self.triangle_ids], robust) if len(self.triangle_ids) else None

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        if self._scene is None:
            n = len(origins)
            return Hits(np.full(n, -1, np.int32), np.full(n, np.inf), np.zeros(n), np.zeros(n))
        hits = self._scene.intersect(origins, directions)
        found = hits.prim >= 0
        hits.prim = np.where(found, self.triangle_ids[np.where(found, hits.prim, 0)], -1)
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        if self._scene is None:
            return np.zeros(len(origins), bool)
        return self._scene.occluded(origins, directions, t_max)
