"""Flatten a SceneSpec into world-space triangle arrays: what renderers and samplers consume."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workers.scene import spec
from workers.scene.budget import check_triangles, max_scene_triangles, placement_field, shape_triangles
from workers.scene.errors import SceneError
from workers.scene.shapes import MeshData, shape_mesh


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
        k: [] for k in ("pos", "nrm", "uv", "mat", "obj", "inst", "emit", "two")
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
            chunks["mat"].append(np.full(n, material_index[obj.material], np.int32))
            chunks["obj"].append(np.full(n, i, np.int32))
            chunks["inst"].append(np.full(n, instance_counter, np.int32))
            chunks["emit"].append(np.tile(np.asarray(obj.emission or (0, 0, 0), np.float32), (n, 1)))
            chunks["two"].append(np.full(n, obj.two_sided_emission, bool))
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
    )
    if isinstance(scene.environment, spec.EnvironmentMap):
        from workers.scene.envmaps import load_environment

        image = load_environment(scene.environment, "environment", base)
        compiled.environment_image = (image * scene.environment.scale).astype(np.float32)
        compiled.environment_rotation = spec.euler_xyz(scene.environment.rotate)
    if not scene.emitters_present():
        raise SceneError("lights", "the scene has no light: add an emitter, a light or an environment")
    return compiled


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
