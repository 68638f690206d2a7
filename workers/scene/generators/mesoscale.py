"""Procedural mesoscale geometry: fur strands, grass blades and carpet loops, in a periodic tangent slab
or grown on the surfaces of any mesh (Diolatzis 2022, Sec. 6.2.3).

Every instance is randomised from its seed; the structure parameters (length as a fraction of the slab
height, density in strands per squared slab height, curliness in [0, 1]) set the distribution it is drawn
from. Strands are built in a local frame (tangent x, y; up z; unit = slab height) and then placed: tiled
periodically over `tiles` x `tiles` copies of a square tile (the neighbouring patches around the one a
camera looks at) and cropped to the slab's height, or rooted on triangles along the interpolated normal.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from workers.scene.format.spec import Structure
from workers.scene.generators.procedural import (
    Generators,
    GroundPlaneParams,
    Params,
    PositiveFloat,
    Seed,
    ground_plane,
    normalized,
    orthonormal_frames,
    tubes,
)
from workers.scene.geometry.mesh import MeshData

MATERIAL_KINDS = ("fur", "grass", "carpet")
MaterialKind = Literal["fur", "grass", "carpet"]
SEGMENTS = 5  # polyline points per strand minus one: enough for a curl of half a turn
SIDES = 3  # a strand is a triangular prism
GENERATORS = Generators()


def local_strands(rng: np.random.Generator, n: int, kind: str, s: Structure) -> tuple[np.ndarray, np.ndarray]:
    """Polylines (n, K, 3) rooted at the origin in the local frame (z up, unit slab height) and their radii.

    Fur leans and curls (a quadratic bend); grass blades rise nearly straight and taper to a point;
    carpet loops are arcs from the root back to the base, like tufted pile, that curliness twists over to
    one side (up to 60 degrees, a frieze pile). Curliness bends every family sideways."""
    k = SEGMENTS + 1
    t = np.linspace(0.0, 1.0, k)[None, :, None]
    length = s.length * rng.uniform(0.8, 1.2, n)[:, None, None]
    azimuth = rng.uniform(0, 2 * np.pi, n)
    side = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros(n)], axis=1)[:, None]
    up = np.array([0.0, 0.0, 1.0])
    if kind == "carpet":
        angle = np.pi * t  # a half loop of height `length` and width `length` / 2
        twist = np.radians(60.0) * s.curliness * rng.uniform(0.5, 1.0, n)[:, None, None]
        across = np.stack([-np.sin(azimuth), np.cos(azimuth), np.zeros(n)], axis=1)[:, None]
        rise = np.cos(twist) * up + np.sin(twist) * across
        centers = length * (0.25 * (1 - np.cos(angle)) * side + np.sin(angle) * rise)
        radius = 0.025 * np.ones((n, k))
    else:
        lean = np.radians(15.0 if kind == "fur" else 6.0) * np.sqrt(rng.uniform(0, 1, n))[:, None, None]
        bend = (0.9 if kind == "fur" else 0.35) * s.curliness
        direction = np.cos(lean) * up + np.sin(lean) * side
        curl_azimuth = azimuth + rng.normal(0.0, 1.0, n)
        curl = np.stack([np.cos(curl_azimuth), np.sin(curl_azimuth), -0.3 * np.ones(n)], axis=1)[:, None]
        centers = length * (t * direction + bend * t * t * normalized(curl))
        root, tip = (0.012, 0.25) if kind == "fur" else (0.03, 0.1)
        radius = root * np.broadcast_to(np.linspace(1.0, tip, k)[None], (n, k))
    centers[..., 2] = np.maximum(centers[..., 2], 0.0)  # never below the base
    return centers, np.array(radius)


class MesoscaleSlabParams(Params):
    material: MaterialKind = "fur"
    seed: Seed = 0
    structure: Structure = Structure()
    tile: PositiveFloat = Field(default=2.0, description="side of the periodic tile, in slab heights")
    tiles: Annotated[int, Field(ge=1, le=9, description="tiles per side around and including the centre")] = 3
    height: PositiveFloat = Field(default=1.0, description="slab height: geometry above it is cropped")

    def strands_per_tile(self) -> int:
        return max(1, round(self.structure.density * self.tile * self.tile))

    def triangles(self) -> int:
        return self.strands_per_tile() * self.tiles**2 * SEGMENTS * SIDES * 2


@GENERATORS.add(MesoscaleSlabParams)
def mesoscale_slab(p: MesoscaleSlabParams) -> MeshData:
    """Strands of one periodic tile repeated over `tiles`^2 tiles centred on the origin, on a base plane
    (y = 0, facing +y, scene axes) and cropped at y = `height`; the strands only (the base is
    `mesoscale_base`, a separate object so that it can carry its own material)."""
    rng = np.random.default_rng(p.seed)
    n = p.strands_per_tile()
    roots = rng.uniform(0.0, p.tile, size=(n, 2))
    centers, radius = local_strands(rng, n, p.material, p.structure)
    offsets = (np.arange(p.tiles) - (p.tiles - 1) / 2) * p.tile - p.tile / 2
    shifts = np.stack(np.meshgrid(offsets, offsets, indexing="ij"), -1).reshape(-1, 2)
    placed = (roots[None] + shifts[:, None]).reshape(-1, 2)
    local = np.tile(centers, (len(shifts), 1, 1)) * p.height
    local[..., :2] += placed[:, None]
    local[..., 2] = np.minimum(local[..., 2], p.height)
    scene_axes = local[..., [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # local z up -> scene y up
    return tubes(scene_axes, np.tile(radius, (len(shifts), 1)) * p.height, SIDES)


class MesoscaleBaseParams(Params):
    tile: PositiveFloat = 2.0
    tiles: Annotated[int, Field(ge=1, le=9)] = 3
    height: PositiveFloat = 1.0

    def triangles(self) -> int:
        return GroundPlaneParams(size=self.tile * self.tiles).triangles()


@GENERATORS.add(MesoscaleBaseParams)
def mesoscale_base(p: MesoscaleBaseParams) -> MeshData:
    """The base (skin) under `mesoscale_slab` with the same tiling."""
    return ground_plane(GroundPlaneParams(size=p.tile * p.tiles))


def grow_on_triangles(
    positions: np.ndarray,
    normals: np.ndarray,
    kind: str,
    structure: Structure,
    height: float,
    seed: int,
) -> MeshData:
    """Strands rooted uniformly by area on triangles `positions` (T, 3, 3) along their interpolated vertex
    `normals` (T, 3, 3), `height` world units per slab height: the real geometry a shell stands in for."""
    rng = np.random.default_rng(seed)
    e1, e2 = positions[:, 1] - positions[:, 0], positions[:, 2] - positions[:, 0]
    areas = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    n = max(1, round(structure.density * areas.sum() / height**2))
    tri = rng.choice(len(positions), size=n, p=areas / areas.sum())
    r1, r2 = rng.uniform(size=n), rng.uniform(size=n)
    flip = r1 + r2 > 1
    b1, b2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
    b = np.stack([1 - b1 - b2, b1, b2], axis=1)[:, :, None]
    roots = (b * positions[tri]).sum(1)
    normal = normalized((b * normals[tri]).sum(1))
    tangent, bitangent = orthonormal_frames(normal)
    centers, radius = local_strands(rng, n, kind, structure)
    centers = np.minimum(centers, [np.inf, np.inf, 1.0]) * height
    world = (
        roots[:, None]
        + centers[..., :1] * tangent[:, None]
        + centers[..., 1:2] * bitangent[:, None]
        + centers[..., 2:] * normal[:, None]
    )
    return tubes(world, radius * height, SIDES)
