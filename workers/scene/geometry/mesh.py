"""The triangle mesh every reader and generator builds, and the test for triangles too thin to render.

A leaf: it imports nothing from the scene package, so every layer that makes or reads meshes can use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEGENERATE_AREA = 1e-14  # relative to the squared bounding-box diagonal


@dataclass(frozen=True)
class MeshData:
    """Indexed triangles; optional per-vertex shading normals, UVs, tangents and colours."""

    vertices: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    normals: np.ndarray | None = None  # (V, 3)
    uvs: np.ndarray | None = None  # (V, 2)
    tangents: np.ndarray | None = None  # (V, 4): xyz and the bitangent's sign (glTF's TANGENT)
    # (V, 3) linear RGB that multiplies the material's base colour (glTF's COLOR_0, a PLY's colours)
    colors: np.ndarray | None = None

    @property
    def num_triangles(self) -> int:
        return len(self.faces)


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def degenerate_triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Which triangles have (relatively) zero area: they would break the renderer's normals and sampling."""
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    return triangle_areas(vertices, faces) <= DEGENERATE_AREA * max(extent, 1e-30) ** 2
