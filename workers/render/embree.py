"""Closest-hit and occlusion queries through Embree (embreex), as `Intersector`s; each releases the GIL."""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from workers.render import heap
from workers.render.intersector import Hits


class RayScene:
    """One Embree scene over world-space triangles (T, 3, 3)."""

    def __init__(self, positions: np.ndarray, robust: bool = True):
        heap.keep_freed_arrays()  # each query allocates arrays of about 1 MB, as the tracer's bounces do
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, np.ascontiguousarray(positions, dtype=np.float32))
        # Embree builds its BVH lazily on the first query: build it now, once, not inside a worker thread.
        self.intersect(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray | None = None) -> Hits:
        """Closest hits; with `t_max` (N,), only those up to it (float32 rounded up: a farther hit may
        still be reported), which lets Embree skip what lies beyond: callers that only keep hits
        closer than a bound pass it."""
        if len(origins) == 0:
            empty = np.zeros(0)
            return Hits(np.zeros(0, np.int32), empty, empty, empty)
        dists = None
        if t_max is not None:
            bound = np.minimum(t_max, 3.0e38).astype(np.float32)
            dists = np.nextafter(bound, np.float32(np.inf))
        out = self._scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            dists=dists,
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

    def intersect(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray | None = None) -> Hits:
        """As `RayScene.intersect`."""
        if self._scene is None:
            return Hits.misses(len(origins))
        hits = self._scene.intersect(origins, directions, t_max)
        found = hits.prim >= 0
        hits.prim = np.where(found, self.triangle_ids[np.where(found, hits.prim, 0)], -1)
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        if self._scene is None:
            return np.zeros(len(origins), bool)
        return self._scene.occluded(origins, directions, t_max)
