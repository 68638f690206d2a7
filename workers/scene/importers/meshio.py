"""Read mesh files (OBJ, PLY, glTF/GLB, STL) with trimesh into one MeshData.

Multi-part files (glTF node hierarchies, OBJ objects) are flattened with their node
transforms. Files are loaded with `process=False` so trimesh never merges vertices
(which would break UV seams). UVs follow Mitsuba's convention, (0, 0) at the top-left
texel: trimesh hands out OBJ-style UVs (origin bottom-left), so v becomes 1 - v, as
Mitsuba's own loaders do. Vertex colours (and a PLY's face colours) multiply the material's base colour:
8-bit colours of OBJ and PLY files are display (sRGB) values and are decoded to linear; glTF's COLOR_0 is
linear by the specification, so colours of glTF/GLB files are taken as they are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from workers.scene.format import spec
from workers.scene.format.errors import SceneError
from workers.scene.geometry.mesh import MeshData
from workers.scene.geometry.shapes import shape_path
from workers.scene.importers.image_io import srgb_to_linear

SUPPORTED_EXTENSIONS = (".obj", ".ply", ".gltf", ".glb", ".stl")


def mesh_shape_mesh(shape: spec.MeshShape, field: str, base_dir: Path | None) -> MeshData:
    """The mesh of a `mesh` shape (`workers.scene.geometry.registry`); errors name its `path`."""
    return load_mesh_file(shape_path(shape.path, base_dir), f"{field}.path")


def load_mesh_file(path: Path, field: str) -> MeshData:
    """Every triangle of the file at `path`, in the file's root space; `field` names it in errors."""
    path = Path(path)
    extension = path.suffix.lower()
    if extension not in SUPPORTED_EXTENSIONS:
        raise SceneError(
            field, f"unsupported mesh format {extension or '(none)'!r}; use {', '.join(SUPPORTED_EXTENSIONS)}"
        )
    if not path.is_file():
        raise SceneError(field, f"mesh file not found: {path}")
    try:
        loaded = trimesh.load(str(path), file_type=extension[1:], process=False)
    except Exception as error:  # trimesh surfaces parser failures as many unrelated exception types
        raise SceneError(field, f"cannot read {path.name}: {type(error).__name__}: {error}") from error
    parts = _placed_parts(loaded)
    if not parts:
        raise SceneError(field, f"{path.name} contains no triangles")
    if any(np.ndim(mesh.vertices) != 2 or np.shape(mesh.vertices)[1] != 3 for mesh, _ in parts):
        # trimesh's OBJ reader returns an [n, 1] array when a `v` line holds fewer than three numbers
        raise SceneError(field, f"cannot read {path.name}: a vertex does not have three coordinates")
    return _concatenate(parts, linear_colors=extension in (".gltf", ".glb"))


def _placed_parts(loaded) -> list[tuple[trimesh.Trimesh, np.ndarray]]:
    """(mesh, node-to-root matrix) for each triangle mesh in what trimesh returned."""
    if isinstance(loaded, trimesh.Trimesh):
        parts = [(loaded, np.eye(4))]
    elif isinstance(loaded, trimesh.Scene):
        parts = []
        for node in loaded.graph.nodes_geometry:
            matrix, geometry_name = loaded.graph[node]
            geometry = loaded.geometry.get(geometry_name)
            if isinstance(geometry, trimesh.Trimesh):
                parts.append((geometry, np.asarray(matrix, dtype=np.float64)))
    else:  # point clouds, paths: nothing to render
        parts = []
    return [(mesh, matrix) for mesh, matrix in parts if len(mesh.faces) > 0]


def _file_normals(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """Vertex normals only if the file stored them (trimesh would otherwise invent smooth ones)."""
    if "vertex_normals" not in mesh._cache:
        return None
    normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    return normals if normals.shape == mesh.vertices.shape else None


def _file_uvs(mesh: trimesh.Trimesh) -> np.ndarray | None:
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        return None
    uv = np.asarray(uv, dtype=np.float64)[:, :2].copy()
    uv[:, 1] = 1.0 - uv[:, 1]
    return uv


def _file_colors(mesh: trimesh.Trimesh, linear: bool) -> np.ndarray | None:
    """(V, 3) linear RGB of a vertex-coloured mesh (see the module's docstring), else None."""
    if mesh.visual.kind != "vertex":
        return None
    rgb = np.asarray(mesh.visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
    return rgb if linear else srgb_to_linear(rgb)


def _unwelded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A face-coloured mesh with its own three vertices per face, its face colours on them (colours are
    per vertex here, and averaging them over shared vertices would blur every edge)."""
    corners = np.asarray(mesh.faces).reshape(-1)
    visual = trimesh.visual.ColorVisuals(vertex_colors=np.repeat(mesh.visual.face_colors, 3, axis=0))
    unwelded = trimesh.Trimesh(
        mesh.vertices[corners], np.arange(len(corners)).reshape(-1, 3), visual=visual, process=False
    )
    if "vertex_normals" in mesh._cache:
        unwelded.vertex_normals = mesh.vertex_normals[corners]
    return unwelded


def _concatenate(parts: list[tuple[trimesh.Trimesh, np.ndarray]], linear_colors: bool) -> MeshData:
    """One indexed mesh; normals/UVs are kept when every part has them (parts without UVs get zeros),
    colours when any part has them (parts without are white)."""
    vertices, faces, normals, uvs, colors = [], [], [], [], []
    offset = 0
    for mesh, matrix in parts:
        if mesh.visual.kind == "face":
            mesh = _unwelded(mesh)
        linear, translation = matrix[:3, :3], matrix[:3, 3]
        v = np.asarray(mesh.vertices, dtype=np.float64)
        f = np.asarray(mesh.faces, dtype=np.int64)
        if np.linalg.det(linear) < 0:  # a mirroring node keeps its faces outward by reversing the winding
            f = f[:, ::-1]
        with np.errstate(invalid="ignore", over="ignore"):  # NaN/Inf vertices are reported by check_mesh
            vertices.append(v @ linear.T + translation)
        faces.append(f + offset)
        n = _file_normals(mesh)
        if n is not None and abs(np.linalg.det(linear)) > 1e-300:
            n = n @ np.linalg.inv(linear)  # inverse-transpose for row vectors
        normals.append(n)
        uvs.append(_file_uvs(mesh))
        colors.append(_file_colors(mesh, linear_colors))
        offset += len(v)
    all_normals = None if any(n is None for n in normals) else np.concatenate(normals)
    all_uvs = None
    if any(uv is not None for uv in uvs):
        all_uvs = np.concatenate(
            [uv if uv is not None else np.zeros((len(v), 2)) for uv, v in zip(uvs, vertices, strict=True)]
        )
    all_colors = None
    if any(c is not None for c in colors):
        all_colors = np.concatenate(
            [c if c is not None else np.ones((len(v), 3)) for c, v in zip(colors, vertices, strict=True)]
        )
    return MeshData(np.concatenate(vertices), np.concatenate(faces), all_normals, all_uvs, colors=all_colors)
