"""Closest-hit and occlusion queries over Embree geometry plus neural objects (LSNIF Sec. 4).

Triangles of neural instances leave the Embree scene. A query first asks Embree about the rest, then
runs a broad phase over the neural instances' world-space boxes (only rays that reach a box before
their current closest hit go on), moves those rays into each instance's local space and asks the
instance's model, batching every instance that shares a model into one inference call. Directions are
transformed but not renormalised, so local and world ray parameters are the same number: moving or
instancing an object needs no retraining.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from workers.render.embree import RayScene
from workers.render.intersector import Hits, SurfaceOverride
from workers.scene.geometry.compile import CompiledScene


class NeuralAnswer(Protocol):
    hit: np.ndarray  # (N,) bool
    t: np.ndarray  # (N,) ray parameter in units of the given direction
    normal: np.ndarray  # (N, 3) local space
    albedo: np.ndarray  # (N, 3)
    material: np.ndarray  # (N,) index into the model's material list


class NeuralGeometry(Protocol):
    """A model answering closest hits of rays given in its local space."""

    def predict(self, origins: np.ndarray, directions: np.ndarray) -> NeuralAnswer: ...


@dataclass
class NeuralInstance:
    """One placement of a neural model in the scene."""

    model: NeuralGeometry
    local_bounds: np.ndarray  # (2, 3) the model's box in local space
    local_to_world: np.ndarray  # (4, 4)
    triangles: tuple[int, int]  # [start, stop) of this instance's triangles in the compiled scene
    material_ids: np.ndarray  # scene material id of each of the model's material indices

    def __post_init__(self) -> None:
        linear = self.local_to_world[:3, :3]
        self.world_to_local_linear = np.linalg.inv(linear)
        corners = np.array(np.meshgrid(*self.local_bounds.T, indexing="ij")).reshape(3, -1).T
        world = corners @ linear.T + self.local_to_world[:3, 3]
        self.world_bounds = np.stack([world.min(0), world.max(0)])

    def to_local(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        inverse_t = self.world_to_local_linear.T
        return (origins - self.local_to_world[:3, 3]) @ inverse_t, directions @ inverse_t

    def normal_to_world(self, normals: np.ndarray) -> np.ndarray:
        world = normals @ self.world_to_local_linear  # the inverse transpose, on row vectors
        return world / np.maximum(np.linalg.norm(world, axis=1, keepdims=True), 1e-300)


def box_entry(
    bounds: np.ndarray, origins: np.ndarray, directions: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(t_near, t_far) of rays against a closed box (slab test; t_near >= 0, empty when t_far < t_near)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        t0 = (bounds[0] - origins) * inv
        t1 = (bounds[1] - origins) * inv
    near = np.where(np.isnan(t0), -np.inf, np.minimum(t0, t1))  # nan: zero direction on the slab's face
    far = np.where(np.isnan(t0), np.inf, np.maximum(t0, t1))
    return np.maximum(near.max(1), 0.0), far.min(1)


class NeuralIntersector:
    """Embree for every triangle outside `instances`, the instances' models for the rest: an `Intersector`
    whose hits on a model carry the predicted surface as their `SurfaceOverride`."""

    def __init__(self, scene: CompiledScene, instances: list[NeuralInstance], robust: bool = True) -> None:
        self.instances = instances
        replaced = np.zeros(scene.num_triangles, bool)
        for instance in instances:
            replaced[instance.triangles[0] : instance.triangles[1]] = True
        self.kept = np.flatnonzero(~replaced).astype(np.int32)
        self.rays = RayScene(scene.positions[self.kept], robust=robust) if len(self.kept) else None
        self.by_model: dict[int, list[NeuralInstance]] = defaultdict(list)
        for instance in instances:
            self.by_model[id(instance.model)].append(instance)
        self.neural_queries = 0  # rays handed to models, for throughput figures

    def _embree(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        if self.rays is None:
            return Hits.misses(len(origins))
        hits = self.rays.intersect(origins, directions)
        hits.prim = np.where(hits.found, self.kept[np.maximum(hits.prim, 0)], -1).astype(np.int32)
        hits.t = np.where(hits.found, hits.t, np.inf)
        return hits

    def _ask_models(self, origins, directions, t_limit):
        """Yield (instance, ray rows, model answer) for rays reaching each instance's box before t_limit."""
        for instances in self.by_model.values():
            rows_all, local_o, local_d, owners = [], [], [], []
            for instance in instances:
                near, far = box_entry(instance.world_bounds, origins, directions)
                rows = np.flatnonzero((far >= near) & (near < t_limit))
                if len(rows) == 0:
                    continue
                lo, ld = instance.to_local(origins[rows], directions[rows])
                rows_all.append(rows), local_o.append(lo), local_d.append(ld), owners.append(instance)
            if not rows_all:
                continue
            answer = instances[0].model.predict(np.concatenate(local_o), np.concatenate(local_d))
            self.neural_queries += sum(len(r) for r in rows_all)
            start = 0
            for instance, rows in zip(owners, rows_all, strict=True):
                part = slice(start, start + len(rows))
                start += len(rows)
                yield instance, rows, answer, part

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        hits = self._embree(origins, directions)
        n = len(origins)
        neural = np.zeros(n, bool)
        normal, albedo = np.zeros((n, 3)), np.zeros((n, 3))
        material = np.zeros(n, np.int64)
        for instance, rows, answer, part in self._ask_models(origins, directions, hits.t):
            t = answer.t[part]
            closer = answer.hit[part] & (t > 0) & (t < hits.t[rows])
            at = rows[closer]
            hits.t[at] = t[closer]
            hits.prim[at] = instance.triangles[0]
            hits.u[at], hits.v[at] = 0.0, 0.0
            neural[at] = True
            normal[at] = instance.normal_to_world(answer.normal[part][closer])
            albedo[at] = answer.albedo[part][closer]
            material[at] = instance.material_ids[answer.material[part][closer]]
        hits.surface = SurfaceOverride(neural, normal, material, albedo)
        return hits

    def occluded(self, origins: np.ndarray, directions: np.ndarray, t_max: np.ndarray) -> np.ndarray:
        blocked = (
            self.rays.occluded(origins, directions, t_max)
            if self.rays is not None
            else np.zeros(len(origins), bool)
        )
        open_rows = np.flatnonzero(~blocked)
        if len(open_rows) == 0 or not self.instances:
            return blocked
        o, d, limit = origins[open_rows], directions[open_rows], np.asarray(t_max, np.float64)[open_rows]
        for _, rows, answer, part in self._ask_models(o, d, limit):
            t = answer.t[part]
            blocked[open_rows[rows[answer.hit[part] & (t > 0) & (t < limit[rows])]]] = True
        return blocked
