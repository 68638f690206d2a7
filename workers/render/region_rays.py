"""Rays that probe a region of the scene (an object's box): training rays for samplers.

`rays_from_bounding_sphere`: origins uniform on the box's circumscribed sphere, directions
cosine-distributed about the inward radial direction (view- and light-independent rays through an
object, for models of an object that must answer any ray).
"""

from __future__ import annotations

import numpy as np

from workers.render.sampling import (
    coordinate_frame,
    square_to_cosine_hemisphere,
    square_to_uniform_sphere,
    to_world,
)


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
