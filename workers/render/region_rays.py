"""Rays that probe a region of the scene (a voxel, an object's box): training rays for samplers.

`rays_entering_box`: origins uniform over the surface of an axis-aligned box, directions
cosine-distributed about the inward face normal (the distribution of radiance entering the box,
as used to prefilter a voxel). `rays_from_bounding_sphere`: origins uniform on the box's
circumscribed sphere, directions cosine-distributed about the inward radial direction (view- and
light-independent rays through an object, as in LSNIF's training).
"""

from __future__ import annotations

import numpy as np

from workers.render.sampling import (
    coordinate_frame,
    square_to_cosine_hemisphere,
    square_to_uniform_sphere,
    to_world,
)

_FACE_AXES = np.array([0, 0, 1, 1, 2, 2])
_FACE_SIDES = np.array([0, 1, 0, 1, 0, 1])


def rays_entering_box(bounds: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(origins, directions) of n rays starting on the box's faces and pointing inside."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    size = hi - lo
    areas = np.repeat([size[1] * size[2], size[0] * size[2], size[0] * size[1]], 2)
    if areas.sum() <= 0:
        raise ValueError("the box has no surface area")
    face = rng.choice(6, size=n, p=areas / areas.sum())
    axis, side = _FACE_AXES[face], _FACE_SIDES[face]
    origins = lo + rng.random((n, 3)) * size
    origins[np.arange(n), axis] = np.where(side == 1, hi[axis], lo[axis])
    inward = np.zeros((n, 3))
    inward[np.arange(n), axis] = np.where(side == 1, -1.0, 1.0)
    return origins, _cosine_about(inward, rng)


def rays_from_bounding_sphere(
    bounds: np.ndarray, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(origins, directions) of n rays from the circumscribed sphere, cosine-weighted towards its centre."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    centre, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12)
    outward = square_to_uniform_sphere(rng.random((n, 2)))
    return centre + radius * outward, _cosine_about(-outward, rng)


def _cosine_about(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    s, t = coordinate_frame(normals)
    return to_world(square_to_cosine_hemisphere(rng.random((len(normals), 2))), s, t, normals)
