"""Named procedural geometry generators, deterministic for their `seed`, fully vectorised.

`generate(name, params, field)` validates `params` with the generator's pydantic model,
so a typo or an out-of-range value names `field.params.<key>` instead of failing later.
Generators build a scene's heavy content (foliage, a ~1M-triangle displaced object, fur)
without shipping mesh files, keeping a SceneSpec small and hashable.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationError, model_validator

from workers.scene.errors import SceneError
from workers.scene.shapes import MeshData

PositiveFloat = Annotated[FiniteFloat, Field(gt=0)]
Seed = Annotated[int, Field(ge=0, lt=2**63)]


class Params(BaseModel):
    """Base for generator parameters: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)


GENERATORS: dict[str, tuple[type[Params], Callable[[Any], MeshData]]] = {}


def generator(params_model: type[Params]):
    """Register a function `fn(params) -> MeshData` under its own name."""

    def register(fn: Callable[[Any], MeshData]) -> Callable[[Any], MeshData]:
        GENERATORS[fn.__name__] = (params_model, fn)
        return fn

    return register


def generate(name: str, params: dict[str, Any], field: str) -> MeshData:
    """The mesh of generator `name` with `params`; errors name `field.generator` or `field.params.<key>`."""
    if name not in GENERATORS:
        raise SceneError(
            f"{field}.generator",
            f"unknown procedural generator {name!r}; known: {', '.join(sorted(GENERATORS))}",
        )
    params_model, fn = GENERATORS[name]
    return fn(parse_params(params_model, params, f"{field}.params"))


def parse_params(model: type[BaseModel], params: dict[str, Any], field: str):
    """`params` validated by `model`; the first problem becomes a SceneError on `field.<key>`."""
    try:
        return model.model_validate(params)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"])
        raise SceneError(f"{field}.{where}" if where else field, first["msg"]) from None


# --------------------------------------------------------------------------- shared building blocks


def orthonormal_frames(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each unit direction (Duff et al. 2017, branch-free and stable)."""
    x, y, z = directions[..., 0], directions[..., 1], directions[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    tangent = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    bitangent = np.stack([b, sign + y * y * a, -y], axis=-1)
    return tangent, bitangent


def normalized(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def tubes(centers: np.ndarray, radii: np.ndarray, sides: int) -> MeshData:
    """Open prisms along polylines: `centers` (N, K, 3), `radii` (N, K) -> N tubes of K - 1 segments.

    Ring frames come from each ring's own tangent, so gently curving tubes twist only slightly;
    normals point radially outward and UVs run (around, along).
    """
    n, k, _ = centers.shape
    tangent, bitangent = orthonormal_frames(normalized(np.gradient(centers, axis=1)))
    angles = 2.0 * np.pi * np.arange(sides) / sides
    radial = (
        np.cos(angles)[None, None, :, None] * tangent[:, :, None]
        + np.sin(angles)[None, None, :, None] * bitangent[:, :, None]
    )  # (N, K, S, 3)
    vertices = centers[:, :, None] + radii[:, :, None, None] * radial
    ring = np.arange(sides)
    a = ring[None, :] + sides * np.arange(k - 1)[:, None]  # (K-1, S): this ring
    b = (ring[None, :] + 1) % sides + sides * np.arange(k - 1)[:, None]  # next around
    quads = np.stack([a, b, b + sides, a + sides], axis=-1).reshape(-1, 4)
    one_tube = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    faces = one_tube[None] + (k * sides * np.arange(n))[:, None, None]
    u = np.broadcast_to((ring / sides)[None, None, :], (n, k, sides))
    v = np.broadcast_to(np.linspace(0.0, 1.0, k)[None, :, None], (n, k, sides))
    return MeshData(
        vertices.reshape(-1, 3),
        faces.reshape(-1, 3),
        radial.reshape(-1, 3),
        np.stack([u, v], axis=-1).reshape(-1, 2),
    )


def quads(centers: np.ndarray, half_u: np.ndarray, half_v: np.ndarray) -> MeshData:
    """Independent rectangles: `center +- half_u +- half_v`, facing `half_u x half_v`, UVs over [0, 1]^2."""
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    vertices = (
        centers[:, None] + corners[None, :, :1] * half_u[:, None] + corners[None, :, 1:] * half_v[:, None]
    )
    normal = normalized(np.cross(half_u, half_v))
    n = len(centers)
    faces = np.array([[0, 1, 2], [0, 2, 3]])[None] + 4 * np.arange(n)[:, None, None]
    uv = np.tile((corners + 1.0) / 2.0, (n, 1))
    uv[:, 1] = 1.0 - uv[:, 1]
    return MeshData(vertices.reshape(-1, 3), faces.reshape(-1, 3), np.repeat(normal, 4, axis=0), uv)


def merge(meshes: list[MeshData]) -> MeshData:
    """Concatenate meshes that all carry normals and UVs."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    return MeshData(
        np.concatenate([m.vertices for m in meshes]),
        np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=True)]),
        np.concatenate([m.normals for m in meshes]),
        np.concatenate([m.uvs for m in meshes]),
    )


def random_unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    return normalized(rng.normal(size=(n, 3)) + 1e-12)


def rotate_towards(axis: np.ndarray, angle: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit vectors at polar `angle` from unit `axis`, at `azimuth` around it (radians)."""
    t, b = orthonormal_frames(axis)
    sin = np.sin(angle)[:, None]
    return normalized(
        np.cos(angle)[:, None] * axis + sin * (np.cos(azimuth)[:, None] * t + np.sin(azimuth)[:, None] * b)
    )


def gradient_noise(points: np.ndarray, seed: int) -> np.ndarray:
    """Seeded 3D Perlin gradient noise in about [-1, 1] (int64 lattice hashing, masked to 8 bits)."""
    rng = np.random.default_rng(seed)
    perm = np.tile(rng.permutation(256), 2).astype(np.int64)
    gradients = random_unit_vectors(rng, 256)
    cell = np.floor(points)
    frac = points - cell
    ix, iy, iz = (cell[:, k].astype(np.int64) & 255 for k in range(3))
    fade = frac * frac * frac * (frac * (frac * 6.0 - 15.0) + 10.0)
    total = np.zeros(len(points))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                h = perm[perm[perm[(ix + dx) & 255] + ((iy + dy) & 255)] + ((iz + dz) & 255)]
                offset = frac - np.array([dx, dy, dz], dtype=np.float64)
                dot = np.einsum("ij,ij->i", gradients[h], offset)
                weight = (
                    (fade[:, 0] if dx else 1.0 - fade[:, 0])
                    * (fade[:, 1] if dy else 1.0 - fade[:, 1])
                    * (fade[:, 2] if dz else 1.0 - fade[:, 2])
                )
                total += weight * dot
    return total * (2.0 / np.sqrt(3.0))  # 3D Perlin noise peaks at sqrt(3)/2 with unit gradients


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, weld: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals; vertices with equal `weld` ids (seam copies) share one normal."""
    face_normals = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )
    ids = weld[faces].reshape(-1)
    size = int(weld.max()) + 1
    summed = np.stack(
        [np.bincount(ids, weights=np.repeat(face_normals[:, k], 3), minlength=size) for k in range(3)], axis=1
    )
    return normalized(summed)[weld]


# --------------------------------------------------------------------------- generators


class GroundPlaneParams(Params):
    size: PositiveFloat = 10.0
    uv_tiles: PositiveFloat = Field(default=1.0, description="how many times UVs repeat across the plane")


@generator(GroundPlaneParams)
def ground_plane(p: GroundPlaneParams) -> MeshData:
    """A square of side `size` in the y = 0 plane facing +y, centred on the origin."""
    h = p.size / 2.0
    plane = quads(np.zeros((1, 3)), np.array([[h, 0.0, 0.0]]), np.array([[0.0, 0.0, -h]]))
    return MeshData(plane.vertices, plane.faces, plane.normals, plane.uvs * p.uv_tiles)


class FractalTreeParams(Params):
    seed: Seed = 0
    depth: Annotated[int, Field(ge=1, le=10)] = 7
    branching: Annotated[int, Field(ge=1, le=6)] = 3
    sides: Annotated[int, Field(ge=3, le=16)] = 5
    trunk_length: PositiveFloat = 1.0
    trunk_radius: PositiveFloat = 0.06
    length_ratio: Annotated[FiniteFloat, Field(gt=0, le=1)] = 0.72
    radius_ratio: Annotated[FiniteFloat, Field(gt=0, le=1)] = 0.62
    spread: Annotated[FiniteFloat, Field(ge=0, le=90, description="branch angle, degrees")] = 32.0
    leaves_per_tip: Annotated[int, Field(ge=0, le=200)] = 12
    leaf_length: PositiveFloat = 0.09
    leaf_width: PositiveFloat = 0.035
    parts: Literal["all", "branches", "leaves"] = Field(
        default="all", description="the same tree's branches or leaves alone, to give each its own material"
    )

    @model_validator(mode="after")
    def _has_geometry(self):
        if self.parts == "leaves" and self.leaves_per_tip == 0:
            raise ValueError("parts='leaves' needs leaves_per_tip > 0")
        return self


@generator(FractalTreeParams)
def fractal_tree(p: FractalTreeParams) -> MeshData:
    """A recursive tree of tapered prisms standing on the origin along +y, with thin leaf quads at the tips.

    Defaults give about 85k triangles (3280 branches, 26k leaves). Generated level by level,
    each level vectorised over all its branches.
    """
    rng = np.random.default_rng(p.seed)
    start = np.zeros((1, 3))
    direction = np.array([[0.0, 1.0, 0.0]])
    length = np.array([p.trunk_length])
    radius = np.array([p.trunk_radius])
    branch_paths, branch_radii = [], []
    for level in range(p.depth + 1):
        end = start + direction * length[:, None]
        tip_radius = radius * p.radius_ratio
        branch_paths.append(np.stack([start, end], axis=1))
        branch_radii.append(np.stack([radius, tip_radius], axis=1))
        if level == p.depth:
            break
        n = len(start) * p.branching
        parent = np.repeat(np.arange(len(start)), p.branching)
        slot = np.tile(np.arange(p.branching), len(start))
        # children spread evenly around the parent with jitter, lean up slightly, and start near its end
        azimuth = 2 * np.pi * (slot + rng.uniform(-0.3, 0.3, n)) / p.branching + rng.uniform(0, 2 * np.pi)
        polar = np.radians(p.spread) * rng.uniform(0.7, 1.3, n)
        child = rotate_towards(direction[parent], polar, azimuth)
        child = normalized(child + np.array([0.0, 0.15, 0.0]))
        along = rng.uniform(0.75, 1.0, n)
        start = start[parent] + direction[parent] * (length[parent] * along)[:, None]
        direction = child
        length = length[parent] * p.length_ratio * rng.uniform(0.85, 1.15, n)
        radius = tip_radius[parent]
    parts = []
    if p.parts in ("all", "branches"):
        parts.append(tubes(np.concatenate(branch_paths), np.concatenate(branch_radii), p.sides))
    if p.parts in ("all", "leaves") and p.leaves_per_tip > 0:
        tips = branch_paths[-1]
        m = len(tips) * p.leaves_per_tip
        owner = np.repeat(np.arange(len(tips)), p.leaves_per_tip)
        t = rng.uniform(0.2, 1.0, m)[:, None]
        stem = tips[owner, 0] + t * (tips[owner, 1] - tips[owner, 0])
        axis = random_unit_vectors(rng, m)
        across = normalized(np.cross(axis, random_unit_vectors(rng, m)))
        scale = rng.uniform(0.7, 1.3, m)[:, None]
        half_length = axis * (0.5 * p.leaf_length) * scale
        parts.append(quads(stem + half_length, half_length, across * (0.5 * p.leaf_width) * scale))
    return merge(parts)


class DisplacedSphereParams(Params):
    seed: Seed = 0
    resolution: Annotated[int, Field(ge=4, le=2000, description="latitude rings; ~4 r^2 triangles")] = 500
    radius: PositiveFloat = 1.0
    amplitude: Annotated[FiniteFloat, Field(ge=0, le=0.8)] = 0.4
    frequency: PositiveFloat = 1.5
    octaves: Annotated[int, Field(ge=1, le=12)] = 6
    gain: Annotated[FiniteFloat, Field(gt=0, le=1)] = 0.5
    lacunarity: Annotated[FiniteFloat, Field(ge=1, le=4)] = 2.0


@generator(DisplacedSphereParams)
def displaced_sphere(p: DisplacedSphereParams) -> MeshData:
    """A UV sphere of `resolution` rings x 2 `resolution` columns displaced along its radius by seeded fBm.

    Default resolution 500 gives 998,000 triangles. UVs follow the sphere convention of
    `shapes.sphere` (u = atan2(x, -z) / 2pi, v = acos(y) / pi); the seam column and the poles
    are duplicated for UVs but share normals, so shading has no seam.
    """
    rows, columns = p.resolution, 2 * p.resolution
    v = np.arange(rows + 1) / rows  # ring 0 and ring `rows` are the poles
    u = np.arange(columns + 1) / columns  # column `columns` duplicates column 0
    uu, vv = np.meshgrid(u, v)
    theta, phi = np.pi * vv.ravel(), 2.0 * np.pi * uu.ravel()
    unit = np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=1)
    fbm = np.zeros(len(unit))
    amplitude, frequency = 1.0, p.frequency
    for octave in range(p.octaves):
        fbm += amplitude * gradient_noise(unit * frequency, p.seed * 1000 + octave)
        amplitude *= p.gain
        frequency *= p.lacunarity
    fbm /= sum(p.gain**k for k in range(p.octaves))
    height = np.clip(1.0 + p.amplitude * fbm, 0.2, None)
    vertices = unit * (p.radius * height)[:, None]

    width = columns + 1
    r, c = np.meshgrid(np.arange(rows), np.arange(columns), indexing="ij")
    a, b = r * width + c, r * width + c + 1
    quad = np.stack([a, b, b + width, a + width], axis=-1)  # counter-clockwise seen from outside
    north = quad[0][:, [0, 2, 3]]
    south = quad[-1][:, [0, 1, 3]]
    middle = quad[1:-1].reshape(-1, 4)
    faces = np.concatenate([north, np.concatenate([middle[:, [0, 1, 2]], middle[:, [0, 2, 3]]]), south])

    weld = np.arange(len(unit)).reshape(rows + 1, width)
    weld[:, -1] = weld[:, 0]  # the seam column shares column 0's normal
    weld[0], weld[-1] = weld[0, 0], weld[-1, 0]  # each pole ring is one point
    normals = vertex_normals(vertices, faces, weld.ravel())
    return MeshData(vertices, faces, normals, np.stack([uu.ravel(), vv.ravel()], axis=1))


class FurParams(Params):
    seed: Seed = 0
    strands: Annotated[int, Field(ge=1, le=200_000)] = 4000
    segments: Annotated[int, Field(ge=1, le=16)] = 4
    sides: Annotated[int, Field(ge=3, le=8)] = 3
    size: PositiveFloat = Field(default=1.0, description="side of the square base plane")
    length: PositiveFloat = 0.12
    radius: PositiveFloat = Field(default=0.003, description="strand radius at the root")
    tip_ratio: Annotated[FiniteFloat, Field(gt=0, le=1)] = 0.2
    curl: Annotated[FiniteFloat, Field(ge=0, le=2, description="bend, as a fraction of the length")] = 0.35
    tilt: Annotated[FiniteFloat, Field(ge=0, le=80, description="max root lean from vertical, degrees")] = (
        25.0
    )


@generator(FurParams)
def fur(p: FurParams) -> MeshData:
    """A square base plane (y = 0, facing +y) with `strands` curved tapered prisms growing from it.

    Each strand is a quadratic curve: it leaves the root leaning up to `tilt` degrees, then
    bends by `curl` x length in a random direction combed slightly towards +x.
    """
    rng = np.random.default_rng(p.seed)
    n, k = p.strands, p.segments + 1
    h = p.size / 2.0
    roots = np.stack([rng.uniform(-h, h, n), np.zeros(n), rng.uniform(-h, h, n)], axis=1)
    lean = np.radians(p.tilt) * np.sqrt(rng.uniform(0, 1, n))
    initial = rotate_towards(np.tile([0.0, 1.0, 0.0], (n, 1)), lean, rng.uniform(0, 2 * np.pi, n))
    bend_azimuth = rng.normal(0.0, 1.0, n)
    bend = np.stack([np.cos(bend_azimuth), -0.3 * np.ones(n), np.sin(bend_azimuth)], axis=1)
    t = np.linspace(0.0, 1.0, k)[None, :, None]
    length = p.length * rng.uniform(0.7, 1.3, n)[:, None, None]
    centers = roots[:, None] + length * (t * initial[:, None] + p.curl * t * t * normalized(bend)[:, None])
    centers[:, :, 1] = np.maximum(centers[:, :, 1], 0.0)  # curls never dip below the base plane
    radii = p.radius * np.broadcast_to(np.linspace(1.0, p.tip_ratio, k)[None], (n, k))
    base = ground_plane(GroundPlaneParams(size=p.size))
    return merge([base, tubes(centers, radii, p.sides)])
