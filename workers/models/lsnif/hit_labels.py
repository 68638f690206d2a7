"""Compiled geometry of LSNIF's reference labels (`workers.models.lsnif.sampling.ObjectReference`): hit
points, normals facing the ray and UVs of a batch of Embree hits in one pass, with no gathers.

float64 throughout (Embree's float32 t, u, v are widened first); serial, `nogil`, cached on disk.
"""

from __future__ import annotations

import math

import numpy as np

from workers.render.jit import njit


@njit(cache=True, nogil=True, fastmath=False)
def hit_geometry(origins, directions, prim, t, u, v, faces, face_normals, normals, uvs):
    """Per ray: position o + t d, the geometric normal and the interpolated shading normal (the geometric
    one where `normals` is empty) both flipped to face the ray, and barycentric UVs (zero where `uvs` is
    empty). Rows with prim < 0 stay zero."""
    n = len(prim)
    position, ng, ns, uv = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 2))
    smooth, textured = len(normals) > 0, len(uvs) > 0
    for i in range(n):
        p = prim[i]
        if p < 0:
            continue
        b1, b2 = u[i], v[i]
        b0 = 1 - b1 - b2
        cos = 0.0
        for a in range(3):
            position[i, a] = origins[i, a] + t[i] * directions[i, a]
            cos += face_normals[p, a] * directions[i, a]
        side = -1.0 if cos > 0 else 1.0
        for a in range(3):
            ng[i, a] = side * face_normals[p, a]
        if smooth:
            c0, c1, c2 = faces[p, 0], faces[p, 1], faces[p, 2]
            sx = b0 * normals[c0, 0] + b1 * normals[c1, 0] + b2 * normals[c2, 0]
            sy = b0 * normals[c0, 1] + b1 * normals[c1, 1] + b2 * normals[c2, 1]
            sz = b0 * normals[c0, 2] + b1 * normals[c1, 2] + b2 * normals[c2, 2]
            scale = side / max(math.sqrt(sx * sx + sy * sy + sz * sz), 1e-300)
            ns[i, 0], ns[i, 1], ns[i, 2] = sx * scale, sy * scale, sz * scale
        else:
            for a in range(3):
                ns[i, a] = ng[i, a]
        if textured:
            c0, c1, c2 = faces[p, 0], faces[p, 1], faces[p, 2]
            for a in range(2):
                uv[i, a] = b0 * uvs[c0, a] + b1 * uvs[c1, a] + b2 * uvs[c2, a]
    return position, ng, ns, uv
