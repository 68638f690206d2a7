"""Flatten a SceneSpec into world-space triangle arrays: what renderers and samplers consume."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.budget import (
    check_triangles,
    max_scene_triangles,
    placement_field,
    shape_triangles,
)
from workers.scene.geometry.mesh import MeshData
from workers.scene.geometry.registry import ENVIRONMENT_IMAGES, registered
from workers.scene.geometry.shapes import shape_mesh


@dataclass(frozen=True)
class ObjectGeometry:
    """One scene object: its local mesh, its placements and where its triangles sit in the flat arrays."""

    name: str
    index: int
    mesh: MeshData
    instance_matrices: list[np.ndarray]
    triangle_ranges: list[tuple[int, int]]  # [start, stop) per instance into CompiledScene arrays
    material: str


@dataclass
class CompiledScene:
    """World-space triangles and per-triangle attributes, one row per triangle of every instance."""

    spec: spec.SceneSpec
    base_dir: Path | None
    positions: np.ndarray  # (T, 3, 3) float32
    shading_normals: np.ndarray  # (T, 3, 3) float32, unit
    uvs: np.ndarray  # (T, 3, 2) float32
    geometric_normals: np.ndarray  # (T, 3) float32, unit, follows winding
    areas: np.ndarray  # (T,) float64
    material_ids: np.ndarray  # (T,) int32, index into material_names
    object_ids: np.ndarray  # (T,) int32
    instance_ids: np.ndarray  # (T,) int32, global instance counter
    emission: np.ndarray  # (T, 3) float32 radiance; zero for non-emitters
    two_sided_emission: np.ndarray  # (T,) bool
    material_names: list[str]
    objects: list[ObjectGeometry]
    environment_image: np.ndarray | None = None  # (H, W, 3) float32 lat-long, already scaled
    environment_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))  # local -> world
    tangents: np.ndarray | None = None  # (T, 3, 4) float32 per corner, when a material has a normal map
    # (T, 3, 3) float32 linear RGB per corner multiplying the base colour, when a mesh has vertex colours
    vertex_colors: np.ndarray | None = None

    @property
    def num_triangles(self) -> int:
        return len(self.positions)

    @property
    def bounds(self) -> np.ndarray:
        flat = self.positions.reshape(-1, 3)
        return np.stack([flat.min(0), flat.max(0)]).astype(np.float64)

    @property
    def extent(self) -> float:
        """Length of the bounding-box diagonal; the unit for scale-relative epsilons."""
        b = self.bounds
        return float(np.linalg.norm(b[1] - b[0]))

    @property
    def materials(self) -> list[spec.Material]:
        return [self.spec.materials[n] for n in self.material_names]


def compile_scene(
    scene: spec.SceneSpec, base_dir: Path | str | None = None, max_triangles: int | None = None
) -> CompiledScene:
    """Load every shape, place every instance, and check what can only be checked on the geometry.

    A scene over `max_triangles` (default: the configured limit, `budget.max_scene_triangles`) is
    refused naming the object that crosses it, before that object is built (after reading, for a file).
    """
    base = Path(base_dir) if base_dir is not None else None
    limit = max_scene_triangles() if max_triangles is None else max_triangles
    material_names = list(scene.materials)
    material_index = {n: i for i, n in enumerate(material_names)}
    chunks: dict[str, list[np.ndarray]] = {
        k: [] for k in ("pos", "nrm", "uv", "mat", "obj", "inst", "emit", "two", "tan", "col")
    }
    normal_mapped = {
        n
        for n, m in scene.materials.items()
        if getattr(spec.surface_material(m), "normal_texture", None) is not None
    }
    objects: list[ObjectGeometry] = []
    start = 0
    instance_counter = 0
    for i, obj in enumerate(scene.objects):
        field_name = f"objects[{i}]"
        matrices = obj.instance_matrices()
        known = shape_triangles(obj.shape, f"{field_name}.shape")
        if known is not None:
            check_triangles(start + known * len(matrices), placement_field(obj, i), limit)
        mesh = shape_mesh(obj.shape, f"{field_name}.shape", base)
        check_triangles(start + mesh.num_triangles * len(matrices), placement_field(obj, i), limit)
        ranges = []
        for m in matrices:
            pos, nrm, faces = _place(mesh, m)
            n = len(pos)
            chunks["pos"].append(pos)
            chunks["nrm"].append(nrm)
            uv = mesh.uvs[faces] if mesh.uvs is not None else np.zeros((n, 3, 2))
            chunks["uv"].append(uv)
            chunks["col"].append(mesh.colors[faces] if mesh.colors is not None else None)
            chunks["mat"].append(np.full(n, material_index[obj.material], np.int32))
            chunks["obj"].append(np.full(n, i, np.int32))
            chunks["inst"].append(np.full(n, instance_counter, np.int32))
            chunks["emit"].append(np.tile(np.asarray(obj.emission or (0, 0, 0), np.float32), (n, 1)))
            chunks["two"].append(np.full(n, obj.two_sided_emission, bool))
            if normal_mapped:
                chunks["tan"].append(_placed_tangents(mesh, m, faces, obj.material in normal_mapped))
            ranges.append((start, start + n))
            start += n
            instance_counter += 1
        objects.append(ObjectGeometry(obj.name, i, mesh, matrices, ranges, obj.material))

    positions = np.concatenate(chunks["pos"]).astype(np.float32)
    e1, e2 = positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0]
    cross = np.cross(e1.astype(np.float64), e2.astype(np.float64))
    length = np.linalg.norm(cross, axis=1)
    areas = 0.5 * length
    for obj in objects:
        if scene.objects[obj.index].emission is None:
            continue
        lo, hi = obj.triangle_ranges[0][0], obj.triangle_ranges[-1][1]
        if areas[lo:hi].sum() <= 0:
            raise SceneError(f"objects[{obj.index}].emission", "emitting object has zero area")
    geometric = (cross / np.maximum(length, 1e-300)[:, None]).astype(np.float32)
    compiled = CompiledScene(
        spec=scene,
        base_dir=base,
        positions=positions,
        shading_normals=np.concatenate(chunks["nrm"]).astype(np.float32),
        uvs=np.concatenate(chunks["uv"]).astype(np.float32),
        geometric_normals=geometric,
        areas=areas,
        material_ids=np.concatenate(chunks["mat"]),
        object_ids=np.concatenate(chunks["obj"]),
        instance_ids=np.concatenate(chunks["inst"]),
        emission=np.concatenate(chunks["emit"]).astype(np.float32),
        two_sided_emission=np.concatenate(chunks["two"]),
        material_names=material_names,
        objects=objects,
        tangents=np.concatenate(chunks["tan"]).astype(np.float32) if normal_mapped else None,
        vertex_colors=_vertex_colors(chunks["col"], chunks["pos"]),
    )
    load_environment = registered(ENVIRONMENT_IMAGES, scene.environment.type) if scene.environment else None
    if load_environment is not None:
        image = load_environment(scene.environment, "environment", base)
        compiled.environment_image = (image * scene.environment.scale).astype(np.float32)
        compiled.environment_rotation = spec.euler_xyz(scene.environment.rotate)
    if not scene.emitters_present():
        raise SceneError("lights", "the scene has no light: add an emitter, a light or an environment")
    return compiled


def _vertex_colors(colors: list[np.ndarray | None], positions: list[np.ndarray]) -> np.ndarray | None:
    """Every instance's corner colours, white where its mesh has none; None when no mesh has any (so
    uncoloured scenes cost nothing)."""
    if all(c is None for c in colors):
        return None
    return np.concatenate(
        [np.ones(p.shape) if c is None else c for c, p in zip(colors, positions, strict=True)]
    ).astype(np.float32)


def _place(mesh: MeshData, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-space corners, shading normals and the face indices used (mirrors reverse the winding)."""
    linear, t = m[:3, :3], m[:3, 3]
    faces = mesh.faces
    if np.linalg.det(linear) < 0:
        faces = faces[:, ::-1]
    pos = mesh.vertices[faces] @ linear.T + t
    if mesh.normals is not None:
        nrm = mesh.normals[faces] @ np.linalg.inv(linear)  # inverse-transpose, row vectors
        nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-300)
    else:
        face_n = np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0])
        face_n /= np.maximum(np.linalg.norm(face_n, axis=-1, keepdims=True), 1e-300)
        nrm = np.repeat(face_n[:, None], 3, axis=1)
    return pos, nrm, faces


def generated_tangents(mesh: MeshData) -> np.ndarray:
    """(V, 4) unit tangents along dP/du, orthogonal to the vertex normal, and the sign that makes
    cross(normal, tangent) * sign point up the image (-dP/dv, as v grows downwards): glTF's convention
    for normal maps. Accumulated over each vertex's triangles; without usable UVs, any orthonormal frame."""
    v, f = mesh.vertices, mesh.faces
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    if mesh.normals is not None:
        normals = mesh.normals
    else:
        normals = np.zeros_like(v)
        np.add.at(normals, f.ravel(), np.repeat(face_n, 3, axis=0))
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    du_dp = np.zeros_like(v)
    dv_dp = np.zeros_like(v)
    if mesh.uvs is not None:
        e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
        t1, t2 = mesh.uvs[f[:, 1]] - mesh.uvs[f[:, 0]], mesh.uvs[f[:, 2]] - mesh.uvs[f[:, 0]]
        det = t1[:, 0] * t2[:, 1] - t2[:, 0] * t1[:, 1]
        r = np.where(np.abs(det) > 1e-20, 1.0 / np.where(det == 0, 1.0, det), 0.0)[:, None]
        np.add.at(du_dp, f.ravel(), np.repeat((e1 * t2[:, 1:] - e2 * t1[:, 1:]) * r, 3, axis=0))
        np.add.at(dv_dp, f.ravel(), np.repeat((e2 * t1[:, :1] - e1 * t2[:, :1]) * r, 3, axis=0))
    tangent = du_dp - normals * np.einsum("ij,ij->i", du_dp, normals)[:, None]
    length = np.linalg.norm(tangent, axis=1)
    fallback = np.cross(normals, np.where(np.abs(normals[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]]))
    tangent = np.where((length > 1e-12)[:, None], tangent / np.maximum(length, 1e-300)[:, None], fallback)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    sign = np.where(np.einsum("ij,ij->i", np.cross(normals, tangent), -dv_dp) < 0, -1.0, 1.0)
    return np.concatenate([tangent, sign[:, None]], axis=1)


def _placed_tangents(mesh: MeshData, m: np.ndarray, faces: np.ndarray, needed: bool) -> np.ndarray:
    """World-space corner tangents (T, 3, 4): the mesh's own (glTF TANGENT) or generated; zeros where no
    normal map reads them. A mirroring placement flips the bitangent's sign."""
    if not needed:
        return np.zeros((len(faces), 3, 4))
    tangents = mesh.tangents if mesh.tangents is not None else generated_tangents(mesh)
    linear = m[:3, :3]
    xyz = tangents[:, :3] @ linear.T
    xyz /= np.maximum(np.linalg.norm(xyz, axis=1, keepdims=True), 1e-300)
    sign = tangents[:, 3:] * np.sign(np.linalg.det(linear))
    return np.concatenate([xyz, sign], axis=1)[faces]
