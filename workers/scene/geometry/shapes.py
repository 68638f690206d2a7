"""Turn a shape description into a checked triangle mesh in the shape's local space: the builder that
`workers.scene.geometry.registry` names for the shape's `type` makes it, and `check_mesh` checks it. The
analytic shapes (rectangle, box, sphere) are built here."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.mesh import MeshData, degenerate_triangles
from workers.scene.geometry.registry import SHAPE_MESHES, registered


def rectangle() -> MeshData:
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    return MeshData(v, np.array([[0, 1, 2], [0, 2, 3]]), n, uv)


def box() -> MeshData:
    """Six rectangles rotated to face outward; flat normals, per-face UVs."""
    face = rectangle()
    rotations = [  # maps +z to each face normal
        np.eye(3),
        np.diag([1.0, -1.0, -1.0]),
        np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=np.float64),
        np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], dtype=np.float64),
        np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], dtype=np.float64),
        np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=np.float64),
    ]
    verts, faces, normals, uvs = [], [], [], []
    for k, r in enumerate(rotations):
        verts.append(face.vertices @ r.T + r[:, 2])
        normals.append(face.normals @ r.T)
        faces.append(face.faces + 4 * k)
        uvs.append(face.uvs)
    return MeshData(
        np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs)
    )


# The icosahedron trimesh's `icosphere` starts from (its `creation` data): the spheres' triangles stay theirs.
_A, _B = 0.5257311121191336, 0.85065080835204
ICOSAHEDRON_VERTICES = np.array(
    [
        [-_A, _B, 0], [_A, _B, 0], [-_A, -_B, 0], [_A, -_B, 0], [0, -_A, _B], [0, _A, _B],
        [0, -_A, -_B], [0, _A, -_B], [_B, 0, -_A], [_B, 0, _A], [-_B, 0, -_A], [-_B, 0, _A],
    ],
    dtype=np.float64,
)  # fmt: skip
ICOSAHEDRON_FACES = np.array(
    [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
        [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
        [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ],
    dtype=np.int64,
)  # fmt: skip


def icosphere(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of the unit icosphere: the triangles of `trimesh.creation.icosphere`, corner for
    corner and bit for bit (its midpoints are numbered in another order), without importing trimesh, which
    was half a second of the start-up of every render of a scene with a sphere."""
    vertices, faces = ICOSAHEDRON_VERTICES, ICOSAHEDRON_FACES
    for _ in range(subdivisions):
        edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        keys, inverse = np.unique(edges[:, 0] * len(vertices) + edges[:, 1], return_inverse=True)
        mid = inverse.reshape(-1, 3) + len(vertices)  # the midpoints of edges 01, 12 and 20 of each face
        a, b, c = faces.T
        ab, bc, ca = mid.T
        faces = np.column_stack([a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca]).reshape(-1, 3)
        ends = np.stack(np.divmod(keys, len(vertices)), axis=1)
        vertices = _onto_unit_sphere(np.vstack((vertices, vertices[ends].mean(axis=1))))
    return (vertices if subdivisions > 0 else _onto_unit_sphere(vertices)), faces


def _onto_unit_sphere(vertices: np.ndarray) -> np.ndarray:
    """Each vertex moved along its direction to radius 1, with trimesh's arithmetic."""
    scalar = np.sqrt(np.dot(vertices**2, [1, 1, 1]))
    return vertices + vertices / scalar.reshape(-1, 1) * (1.0 - scalar).reshape(-1, 1)


def sphere(center, radius: float, subdivisions: int) -> MeshData:
    """An icosphere with smooth normals and spherical UVs (seam triangles share vertices; fine for tests)."""
    vertices, faces = icosphere(subdivisions)
    unit = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    u = np.arctan2(unit[:, 0], -unit[:, 2]) / (2 * np.pi) % 1.0
    v = np.arccos(np.clip(unit[:, 1], -1, 1)) / np.pi
    return MeshData(unit * radius + np.asarray(center), faces, unit, np.stack([u, v], 1))


def rectangle_mesh(shape: spec.RectangleShape, field: str, base_dir: Path | None) -> MeshData:
    return rectangle()


def box_mesh(shape: spec.BoxShape, field: str, base_dir: Path | None) -> MeshData:
    return box()


def sphere_mesh(shape: spec.SphereShape, field: str, base_dir: Path | None) -> MeshData:
    return sphere(shape.center, shape.radius, shape.subdivisions)


def rectangle_triangles(shape: spec.RectangleShape, field: str) -> int:
    return 2


def box_triangles(shape: spec.BoxShape, field: str) -> int:
    return 12


def sphere_triangles(shape: spec.SphereShape, field: str) -> int:
    return 20 * 4**shape.subdivisions  # an icosphere: each subdivision splits a face in four


def shape_path(path: str, base_dir: Path | None) -> Path:
    """The file a shape reads: a relative `path` resolves against the scene's folder `base_dir`."""
    resolved = Path(path)
    return base_dir / resolved if not resolved.is_absolute() and base_dir is not None else resolved


def shape_mesh(shape: spec.Shape, field: str, base_dir: Path | None = None) -> MeshData:
    """The checked local-space mesh of `shape`; `field` names it in errors."""
    build = registered(SHAPE_MESHES, shape.type)
    if build is None:
        raise SceneError(field, f"unsupported shape {type(shape).__name__}")
    return check_mesh(build(shape, field, base_dir), field, repair=getattr(shape, "repair", False))


def check_mesh(mesh: MeshData, field: str, repair: bool = False) -> MeshData:
    """Reject (or with `repair` drop) what would break the renderer: non-finite data, bad indices, slivers."""
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise SceneError(field, f"expected (V, 3) vertices and (F, 3) faces, got {v.shape} and {f.shape}")
    if len(f) == 0:
        raise SceneError(field, "mesh has no triangles")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise SceneError(
            field, f"{int(bad.sum())} vertices are NaN or Inf (first at index {int(np.argmax(bad))})"
        )
    if f.min() < 0 or f.max() >= len(v):
        raise SceneError(field, f"face indices out of range [0, {len(v)})")
    degenerate = degenerate_triangles(v, f)
    normals, uvs = mesh.normals, mesh.uvs
    if degenerate.all():
        raise SceneError(field, "every triangle is degenerate (zero area)")
    if degenerate.any():
        if not repair:
            raise SceneError(
                field,
                f"{int(degenerate.sum())} degenerate (zero-area) triangles, first at index "
                f"{int(np.argmax(degenerate))}; set `repair: true` on the shape to drop them",
            )
        f = f[~degenerate]
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        if normals.shape != v.shape or not np.isfinite(normals).all() or (length < 1e-12).any():
            normals = None  # unusable shading normals: fall back to flat shading
        else:
            normals = normals / length
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64)
        if uvs.shape != (len(v), 2) or not np.isfinite(uvs).all():
            raise SceneError(field, "texture coordinates are malformed or not finite")
    tangents = mesh.tangents
    if tangents is not None and (tangents.shape != (len(v), 4) or not np.isfinite(tangents).all()):
        tangents = None  # unusable tangents: generated from the UVs instead
    colors = mesh.colors
    if colors is not None:
        colors = np.asarray(colors, dtype=np.float64)
        if colors.shape != (len(v), 3) or not np.isfinite(colors).all() or (colors < 0).any():
            raise SceneError(field, "vertex colours are malformed, negative or not finite")
    return MeshData(v, f, normals, uvs, tangents, colors)
