"""Closest-hit and occlusion queries through Embree (embreex); each call releases the GIL."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh


@dataclass
class Hits:
    """Closest hits of a batch of rays; `prim` is -1 where the ray escaped."""

    prim: np.ndarray  # (N,) int32 triangle index into the compiled scene
    t: np.ndarray  # (N,) float64 distance along the (unit) direction
    u: np.ndarray  # (N,) barycentric weight of vertex 1
    v: np.ndarray  # (N,) barycentric weight of vertex 2

    @property
    def found(self) -> np.ndarray:
        return self.prim >= 0


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
