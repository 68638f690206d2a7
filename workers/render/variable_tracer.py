"""Path tracing a variable scene at any v: one BVH over the static triangles for every state, a small one
over the moved objects per state (as moved objects are instances over a static scene in a two-level BVH).
"""

from __future__ import annotations

import numpy as np

from workers.render.embree import SubsetRayScene
from workers.render.integrator import PathTracer
from workers.render.intersector import Hits
from workers.scene.geometry.variable_scene import CompiledVariableScene, SceneState


class LayeredIntersector:
    """The closer hit of two intersectors over disjoint triangles of one scene; occluded by either."""

    def __init__(self, static: SubsetRayScene, moved: SubsetRayScene) -> None:
        self.static, self.moved = static, moved

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        a = self.static.intersect(origins, directions)
        b = self.moved.intersect(origins, directions)
        closer = np.where(a.found, a.t, np.inf) > np.where(b.found, b.t, np.inf)
        return Hits(
            np.where(closer, b.prim, a.prim),
            np.where(closer, b.t, a.t),
            np.where(closer, b.u, a.u),
            np.where(closer, b.v, a.v),
        )

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        return self.static.occluded(origins, directions, t_max) | self.moved.occluded(
            origins, directions, t_max
        )


class VariableTracer:
    """`at(v)`: a `PathTracer` of the scene at v that shares the static BVH built here once."""

    def __init__(self, scene: CompiledVariableScene, robust: bool = True) -> None:
        self.scene = scene
        self.robust = robust
        self.static = SubsetRayScene(scene.base.positions, scene.static_triangles, robust)

    def state_tracer(self, state: SceneState) -> PathTracer:
        moved = SubsetRayScene(state.compiled.positions, state.visible_moved_triangles, self.robust)
        return PathTracer(state.compiled, intersector=LayeredIntersector(self.static, moved))

    def at(self, v) -> PathTracer:
        return self.state_tracer(self.scene.at(v))
