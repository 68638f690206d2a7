"""Training rays for one LSNIF object and their labels from Embree (Sec. 5.2), as a sample source.

Half of every batch starts on a sphere around the object's box (uniform origins, cosine-weighted towards
its centre); half starts on the surface, at points found by tracing rays of the first kind, with
cosine-weighted directions about the normal on the side the finding ray came from (the side secondary
rays leave from). Nothing depends on a camera or a light, so one model serves any view and lighting.
Everything happens in the object's local space; batch i is a pure function of (seed, i).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch

from workers.models.lsnif.config import LsnifConfig
from workers.models.lsnif.hit_labels import hit_geometry
from workers.models.lsnif.network import network_inputs
from workers.render.embree import RayScene
from workers.render.integrator import PathTracer
from workers.render.materials import MaterialTable
from workers.render.region_rays import rays_from_bounding_sphere
from workers.render.sampling import coordinate_frame, square_to_cosine_hemisphere, to_world
from workers.render.voxels import VoxelGrid, voxelize
from workers.runtime.sources import Batch, batch_rng
from workers.scene.geometry.compile import CompiledScene
from workers.scene.geometry.mesh import MeshData
from workers.scene.portability.reference import SceneRef

SURFACE_SEARCH_ROUNDS = 8


@dataclass
class Labels:
    """Reference answers for N rays in local space (meaningful where `hit`)."""

    hit: np.ndarray  # (N,) bool
    t: np.ndarray  # (N,)
    position: np.ndarray  # (N, 3)
    geometric_normal: np.ndarray  # (N, 3), facing the ray (against its direction)
    normal: np.ndarray  # (N, 3) interpolated shading normal, flipped with the geometric one
    albedo: np.ndarray  # (N, 3)
    material: np.ndarray  # (N,) index into the object's material list


class ObjectReference:
    """Exact closest hits on one object's local mesh through its own Embree BVH: the labels."""

    def __init__(self, mesh: MeshData, material_ids: np.ndarray, materials: MaterialTable) -> None:
        self.mesh = mesh
        self.triangles = mesh.vertices[mesh.faces]
        self.rays = RayScene(self.triangles)
        e1, e2 = self.triangles[:, 1] - self.triangles[:, 0], self.triangles[:, 2] - self.triangles[:, 0]
        cross = np.cross(e1, e2)
        self.face_normals = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
        self.material_ids = material_ids  # scene material id of each of the object's materials
        self.materials = materials
        self._normals = _f64(np.zeros((0, 3)) if mesh.normals is None else mesh.normals)
        self._uvs = _f64(np.zeros((0, 2)) if mesh.uvs is None else mesh.uvs)

    def intersect(self, origins: np.ndarray, directions: np.ndarray, albedo: bool = True) -> Labels:
        """Labels of the rays' closest hits. Normals face the ray: thin two-sided geometry (leaves,
        strands) is hit from both sides, and a winding-signed label would ask the sign-sensitive cosine
        loss for a sign the ray's inputs barely show; the path tracer orients normals towards the ray
        anyway. `albedo=False` leaves albedos at zero (rays that only look for surface points)."""
        origins = np.ascontiguousarray(origins, np.float64)
        directions = np.ascontiguousarray(directions, np.float64)
        hits = self.rays.intersect(origins, directions)
        found = hits.found
        position, ng, ns, uv = hit_geometry(
            origins, directions, np.asarray(hits.prim, np.int64), _f64(hits.t), _f64(hits.u), _f64(hits.v),
            self.mesh.faces, self.face_normals, self._normals, self._uvs,
        )  # fmt: skip
        material = np.zeros(len(origins), np.int64)
        base = np.zeros((len(origins), 3))
        if albedo and found.any():
            sel = np.flatnonzero(found)
            base[sel] = self.materials.surfaces(self.material_ids[material[sel]], uv[sel]).base
            if self.mesh.colors is not None:
                base[sel] *= hits.take(sel).interpolate(self.mesh.colors[self.mesh.faces[hits.prim[sel]]])
        return Labels(found, np.where(found, hits.t, np.inf), position, ng, ns, base, material)


def cosine_about(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    s, t = coordinate_frame(normals)
    return to_world(square_to_cosine_hemisphere(rng.random((len(normals), 2))), s, t, normals)


def training_rays(
    grid: VoxelGrid, reference: ObjectReference, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """n rays: half from the bounding sphere, half from surface points (all from the sphere if the
    object shows no surface to the sphere's rays)."""
    n_surface = n // 2
    origins, directions = rays_from_bounding_sphere(grid.bounds, n - n_surface, rng)
    found_o, found_d = [], []
    remaining = n_surface
    for _ in range(SURFACE_SEARCH_ROUNDS):
        if remaining <= 0:
            break
        probe_o, probe_d = rays_from_bounding_sphere(grid.bounds, 2 * remaining + 64, rng)
        labels = reference.intersect(probe_o, probe_d, albedo=False)
        sel = np.flatnonzero(labels.hit)[:remaining]
        if len(sel) == 0:
            continue
        ng = labels.geometric_normal[sel]  # faces the side the probe came from
        direction = cosine_about(ng, rng)
        found_o.append(PathTracer.offset(labels.position[sel], ng, direction))
        found_d.append(direction)
        remaining -= len(sel)
    if remaining > 0:
        extra_o, extra_d = rays_from_bounding_sphere(grid.bounds, remaining, rng)
        found_o.append(extra_o)
        found_d.append(extra_d)
    return np.concatenate([origins, *found_o]), np.concatenate([directions, *found_d])


def label_batch(grid: VoxelGrid, max_points: int, reference: ObjectReference, origins, directions) -> Batch:
    """Network inputs and reference outputs of the rays that meet an occupied voxel, as float32/int64
    tensors. The others are certain misses that `LsnifObject.predict` answers without the network (a
    third of the sphere's rays): training on them would spend steps on a constant."""
    encoded = network_inputs(grid, origins, directions, max_points)
    reach = np.flatnonzero(encoded.walk.count > 0)
    encoded = encoded.take(reach)
    walk = encoded.walk
    labels = reference.intersect(origins[reach], directions[reach])
    span = np.maximum(walk.t_far - walk.t_near, 1e-300)
    local = np.clip(np.where(labels.hit, (labels.t - walk.t_near) / span, 0.0), 0.0, 1.0)
    return {
        "points": torch.from_numpy(encoded.points),
        "valid": torch.from_numpy(encoded.valid),
        "hit": torch.from_numpy(labels.hit.astype(np.float32)),
        "distance": torch.from_numpy(local.astype(np.float32)),
        "normal": torch.from_numpy(labels.normal.astype(np.float32)),
        "albedo": torch.from_numpy(labels.albedo.astype(np.float32)),
        "material": torch.from_numpy(labels.material),
    }


@dataclass(frozen=True)
class ObjectSourceConfig:
    scene: SceneRef
    object_index: int
    lsnif: LsnifConfig


@dataclass
class PreparedObject:
    """An object's local mesh, its voxels and its reference, built once per process."""

    grid: VoxelGrid
    reference: ObjectReference
    material_names: list[str]


def prepare_object(compiled: CompiledScene, object_index: int, resolution: int) -> PreparedObject:
    geometry = compiled.objects[object_index]
    material_id = compiled.material_names.index(geometry.material)
    reference = ObjectReference(geometry.mesh, np.array([material_id]), MaterialTable(compiled))
    grid = voxelize(geometry.mesh.vertices, geometry.mesh.faces, resolution)
    return PreparedObject(grid, reference, [geometry.material])


class ObjectRaySource:
    """The sample source of one object's training: runs in sampler actors or in process."""

    def __init__(self, config: ObjectSourceConfig, seed: int) -> None:
        self.config = config
        self.seed = seed

    @cached_property
    def prepared(self) -> PreparedObject:
        compiled = self.config.scene.compiled()
        return prepare_object(compiled, self.config.object_index, self.config.lsnif.voxel_resolution)

    def batch(self, index: int) -> Batch:
        prepared, lsnif = self.prepared, self.config.lsnif
        rng = batch_rng(self.seed, index)
        origins, directions = training_rays(prepared.grid, prepared.reference, lsnif.batch_size, rng)
        return label_batch(prepared.grid, lsnif.max_points, prepared.reference, origins, directions)


def _f64(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array, np.float64)
