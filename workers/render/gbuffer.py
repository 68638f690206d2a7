"""First-hit G-buffers through pixel centres (or given points in each pixel), for a whole image or a crop
window of it.

One ray per pixel centre, so a window's buffers are exactly the crop of the full image's (unlike the
jittered, averaged AOVs of `render`): what a neural renderer reads per pixel at training and at inference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer


@dataclass
class GBuffers:
    """Per-pixel first-hit attributes (H, W, C) float32; zeros where the ray escaped (`hit` False)."""

    position: np.ndarray
    normal: np.ndarray  # shading normal
    wo: np.ndarray  # unit direction from the hit back to the camera
    albedo: np.ndarray
    roughness: np.ndarray  # (H, W, 1): GGX alpha, 1 for Lambertian surfaces
    emission: np.ndarray  # radiance emitted towards the camera
    hit: np.ndarray  # (H, W) bool


def primary_gbuffers(
    tracer: PathTracer,
    camera: PinholeCamera,
    window: tuple[int, int, int, int] | None = None,
    offsets: np.ndarray | None = None,
) -> GBuffers:
    """G-buffers of pixels x0 <= x < x1, y0 <= y < y1 (default: the whole image) through pixel centres, or
    through n points per pixel at `offsets` (n, 2) in [0, 1)^2 from its corner: then (H, W * n) with each
    pixel's n samples side by side (for antialiased frames)."""
    x0, y0, x1, y1 = window or (0, 0, camera.width, camera.height)
    if not (0 <= x0 < x1 <= camera.width and 0 <= y0 < y1 <= camera.height):
        raise ValueError(
            f"window: {window} is not a non-empty window of the {camera.width}x{camera.height} image"
        )
    offsets = np.array([[0.5, 0.5]]) if offsets is None else np.asarray(offsets, np.float64)
    ys, xs = np.mgrid[y0:y1, x0:x1]
    px = (xs[..., None] + offsets[:, 0]).ravel()
    py = (ys[..., None] + offsets[:, 1]).ravel()
    origins, directions = camera.rays(px, py)
    rec = tracer.first_hits(origins, directions)
    h, w = y1 - y0, (x1 - x0) * len(offsets)
    hit = rec.hit[:, None]

    def image(values: np.ndarray) -> np.ndarray:
        return np.where(hit, values, 0.0).reshape(h, w, -1).astype(np.float32)

    return GBuffers(
        position=image(rec.position),
        normal=image(rec.shading_normal),
        wo=image(-directions),
        albedo=image(rec.albedo),
        roughness=image(rec.roughness[:, None]),
        emission=image(rec.emission),
        hit=rec.hit.reshape(h, w),
    )
