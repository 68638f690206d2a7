"""UVs for covered surfaces that have none (a mesh file without texture coordinates, a scan): a box
projection. Each triangle takes the coordinate plane its normal points at most (as a cube map's faces
do), with u and v along that plane's axes, so the plane keeps its texel size up to a factor of sqrt(3) on
slanted triangles and the texture is continuous within each of the six charts; where a surface turns
from one chart to the next it has a seam, as a UV layout's islands do. All projected triangles share one
scale and origin (their bounding box's largest side spans the UV square)."""

from __future__ import annotations

import numpy as np


def uv_areas(uvs: np.ndarray) -> np.ndarray:
    """The UV area of each triangle (T, 3, 2)."""
    e1, e2 = uvs[:, 1] - uvs[:, 0], uvs[:, 2] - uvs[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def box_projected(positions: np.ndarray) -> np.ndarray:
    """UVs (T, 3, 2) in [0, 1]^2 of triangles (T, 3, 3) (module docstring). (u, v, normal) is
    right-handed on every chart, so the shell's frame is never mirrored."""
    p = np.asarray(positions, np.float64)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    axis = np.abs(normal).argmax(1)
    facing = np.take_along_axis(normal, axis[:, None], 1)[:, 0] > 0
    after, next_after = (axis + 1) % 3, (axis + 2) % 3
    u_axis, v_axis = np.where(facing, after, next_after), np.where(facing, next_after, after)
    corners = p.reshape(-1, 3)
    scaled = (p - corners.min(0)) / max(float(np.ptp(corners, 0).max()), 1e-300)
    along = lambda a: np.take_along_axis(scaled, np.repeat(a[:, None, None], 3, 1), 2)[..., 0]  # noqa: E731
    return np.stack([along(u_axis), along(v_axis)], -1)


def laid_out(uvs: np.ndarray, positions: np.ndarray, objects: np.ndarray) -> np.ndarray:
    """Covered triangles' UVs (T, 3, 2): their own, or, for each object whose triangles here have no UV
    area (every UV equal: the mesh had none), the box projection of all such objects together."""
    uvs = np.array(uvs, np.float64)
    area = uv_areas(uvs)
    bare = [o for o in np.unique(objects) if area[objects == o].sum() <= 0]
    missing = np.isin(objects, bare)
    if missing.any():
        uvs[missing] = box_projected(positions[missing])
    return uvs
