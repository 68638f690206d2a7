"""First-hit G-buffers through pixel centres (or given points in each pixel), for a whole image or a crop
window of it.

One ray per pixel centre, so a window's buffers are exactly the crop of the full image's (unlike the
jittered, averaged AOVs of `render`): what a neural renderer reads per pixel at training and at inference.

Optionally the buffers follow mirrors (thesis Fig. 5.10, the hybrid that traces specular bounces into the
G-buffer): where a camera ray hits a near-smooth conductor, the ray is reflected about the shading normal
and the buffers describe the surface it reaches, up to `mirror_bounces` times. `throughput` is the product
of the mirrors' specular colours along the way (the conductor's Fresnel term, `bsdfs.conductor`), so a
pixel's radiance is `throughput` times the radiance leaving the buffers' surface towards the last mirror:
a network reads an ordinary surface there and does not have to learn the reflection.

A camera ray that escapes has no surface: its buffers are zeros but for `emission`, the environment's
radiance along it, which is the pixel's exact radiance. A network reading these buffers passes it through
rather than learning the background. (A mirror's reflection that escapes leaves the mirror in the
buffers: `_through_mirrors`.)
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from workers.render.camera import PinholeCamera
from workers.render.integrator import PathTracer, SurfaceRecords
from workers.scene.format import spec

# GGX alpha at or below which a conductor is followed as a mirror: its lobe is a few degrees wide, so the
# reflection of one direction stands for the whole lobe (mirror_variable's mirror is 0.01)
MIRROR_ROUGHNESS = 0.05


def is_mirror(material: spec.Material) -> bool:
    """Whether G-buffers that follow mirrors reflect off surfaces of `material`."""
    return isinstance(material, spec.Conductor) and material.roughness <= MIRROR_ROUGHNESS


@dataclass
class GBuffers:
    """Per-pixel first-hit attributes (H, W, C) float32; zeros where the ray escaped (`hit` False), but for
    `emission`: there the environment's radiance along the escaped ray."""

    position: np.ndarray
    normal: np.ndarray  # shading normal
    wo: np.ndarray  # unit direction from the hit back to the camera
    albedo: np.ndarray
    roughness: np.ndarray  # (H, W, 1): GGX alpha, 1 for Lambertian surfaces
    emission: np.ndarray  # radiance emitted towards the camera (or the last mirror), or the environment's
    hit: np.ndarray  # (H, W) bool
    throughput: np.ndarray  # (H, W, 3): the mirrors' colours the pixel sees the surface through (1: none)


def primary_gbuffers(
    tracer: PathTracer,
    camera: PinholeCamera,
    window: tuple[int, int, int, int] | None = None,
    offsets: np.ndarray | None = None,
    mirror_bounces: int = 0,
) -> GBuffers:
    """G-buffers of pixels x0 <= x < x1, y0 <= y < y1 (default: the whole image) through pixel centres, or
    through n points per pixel at `offsets` (n, 2) in [0, 1)^2 from its corner: then (H, W * n) with each
    pixel's n samples side by side (for antialiased frames); through up to `mirror_bounces` mirrors."""
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
    throughput = np.ones((len(directions), 3))
    if mirror_bounces:
        mirrors = np.array([is_mirror(m) for m in tracer.scene.materials])  # by material id
        settled = np.zeros(len(directions), bool)
        for _ in range(mirror_bounces):
            directions = _through_mirrors(tracer, mirrors, rec, directions, throughput, settled)
    h, w = y1 - y0, (x1 - x0) * len(offsets)
    hit = rec.hit[:, None]
    emission = np.where(hit, rec.emission, 0.0)
    escaped = np.flatnonzero(~rec.hit)
    emission[escaped] = tracer.lights.environment_lookup(directions[escaped])[0]

    def image(values: np.ndarray) -> np.ndarray:
        return np.where(hit, values, 0.0).reshape(h, w, -1).astype(np.float32)

    return GBuffers(
        position=image(rec.position),
        normal=image(rec.shading_normal),
        wo=image(-directions),
        albedo=image(rec.albedo),
        roughness=image(rec.roughness[:, None]),
        emission=emission.reshape(h, w, 3).astype(np.float32),
        hit=rec.hit.reshape(h, w),
        throughput=throughput.reshape(h, w, 3).astype(np.float32),
    )


def _through_mirrors(
    tracer: PathTracer, mirrors: np.ndarray, rec: SurfaceRecords, directions: np.ndarray,
    throughput: np.ndarray, settled: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Replace, in place, the records of rays that hit a mirror (`mirrors[material id]`, not emitting, not
    `settled`) and whose reflection about the shading normal reaches a surface by that surface's,
    multiplying `throughput` by the mirror's colour; the rays' new directions. A reflection that escapes
    keeps the mirror as the pixel's surface, emitting the environment it reflects (its colour times the
    radiance along the reflection): what a near-mirror's GGX tail adds there (a few thousandths where
    `mirror_variable`'s mirror shows the room's open front) is the network's to learn from the mirror's
    own buffers. Such rays are marked `settled`, so later bounces do not trace them again."""
    mirror = rec.hit & mirrors[np.maximum(rec.material_id, 0)] & ~rec.emission.any(axis=1) & ~settled
    rows = np.flatnonzero(mirror)
    if len(rows) == 0:
        return directions
    d, n = directions[rows], rec.shading_normal[rows]
    reflected = d - 2.0 * np.einsum("ij,ij->i", d, n)[:, None] * n  # w_r = d - 2 (d . n) n
    origins = tracer.offset(rec.position[rows], rec.geometric_normal[rows], reflected)
    seen = tracer.first_hits(origins, reflected)
    escaped = rows[~seen.hit]
    settled[escaped] = True
    rec.emission[escaped] = rec.albedo[escaped] * tracer.lights.environment_lookup(reflected[~seen.hit])[0]
    rows, reflected = rows[seen.hit], reflected[seen.hit]
    throughput[rows] *= rec.albedo[rows]
    for field in fields(rec):
        getattr(rec, field.name)[rows] = getattr(seen, field.name)[seen.hit]
    directions = directions.copy()
    directions[rows] = reflected
    return directions
