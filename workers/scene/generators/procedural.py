"""Named procedural geometry generators, deterministic for their `seed`, fully vectorised.

`generate(name, params, field)` (`workers.scene.generators.catalogue`) validates `params` with the
generator's pydantic model, so a typo or an out-of-range value names `field.params.<key>` instead of failing
later. Generators build a scene's heavy content (foliage, a ~1M-triangle displaced object, fur)
without shipping mesh files, keeping a SceneSpec small and hashable.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    FiniteFloat,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from workers.scene.format.errors import SceneError
from workers.scene.format.spec import Vec3
from workers.scene.geometry.mesh import MeshData
from workers.scene.geometry.shapes import box

PositiveFloat = Annotated[FiniteFloat, Field(gt=0)]
Seed = Annotated[int, Field(ge=0, lt=2**63)]


class Params(BaseModel):
    """Base for generator parameters: unknown keys are errors."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    @abstractmethod
    def triangles(self) -> int:
        """How many triangles the generator makes (an upper bound where it is random), from the
        parameters alone: what a budget checks before anything is built."""


class Generators(dict[str, tuple[type[Params], Callable[[Any], MeshData]]]):
    """Generators by name, each with its parameters' model. A module's generators register in its own table
    (`@GENERATORS.add(ParamsModel)`), and `workers.scene.generators.catalogue` joins the tables: a generator
    is known because the catalogue imports its module, not because something imported it for its effect."""

    def add(self, params_model: type[Params]):
        """Register a function `fn(params) -> MeshData` under its own name."""

        def register(fn: Callable[[Any], MeshData]) -> Callable[[Any], MeshData]:
            self[fn.__name__] = (params_model, fn)
            return fn

        return register


GENERATORS = Generators()  # this module's; the catalogue has every generator


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


def grid_surface(occupied: np.ndarray, edges: tuple[np.ndarray, np.ndarray, np.ndarray]) -> MeshData:
    """The boundary of a union of cells of a rectilinear grid, without the faces between two occupied cells.

    `occupied` is (X, Y, Z) bool and `edges` the increasing cell boundaries per axis (X + 1, Y + 1
    and Z + 1 values). Every boundary face is a whole grid face, so neighbouring quads share whole
    edges (no T-junctions) and the surface is closed. Quads face out of the occupied cells, each as two
    consecutive triangles. Quads with the same facing share vertices, so normals stay flat; UVs
    project each face onto its own plane, divided by the largest extent of the grid.
    """
    padded = np.pad(occupied, 1)  # a border of empty cells closes the outside
    points = tuple(len(e) for e in edges)
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])  # counter-clockwise seen from +axis
    keys = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        cells = np.transpose(padded, (a, b, c))[:, 1:-1, 1:-1]
        below, above = cells[:-1], cells[1:]  # the two cells on either side of lattice plane p
        for negative, mask, order in ((0, below & ~above, square), (1, ~below & above, square[::-1])):
            p, j, k = np.nonzero(mask)
            lattice = np.empty((len(p), 4, 3), dtype=np.int64)
            lattice[..., a] = p[:, None]
            lattice[..., b] = j[:, None] + order[:, 0]
            lattice[..., c] = k[:, None] + order[:, 1]
            flat = np.ravel_multi_index((lattice[..., 0], lattice[..., 1], lattice[..., 2]), points)
            keys.append((2 * a + negative) * int(np.prod(points)) + flat)  # facing id, then lattice point
    unique, corners = np.unique(np.concatenate(keys), return_inverse=True)
    corners = corners.reshape(-1, 4)
    facing, flat = np.divmod(unique, int(np.prod(points)))
    index = np.unravel_index(flat, points)
    vertices = np.stack([edges[k][index[k]] for k in range(3)], axis=1)
    axis = facing // 2
    normals = np.zeros_like(vertices)
    normals[np.arange(len(vertices)), axis] = np.where(facing % 2 == 0, 1.0, -1.0)
    low = np.array([e[0] for e in edges])
    extent = max(e[-1] - e[0] for e in edges)
    projected = (vertices - low) / extent
    rows = np.arange(len(vertices))
    uvs = np.stack([projected[rows, (axis + 1) % 3], projected[rows, (axis + 2) % 3]], axis=1)
    faces = np.stack([corners[:, [0, 1, 2]], corners[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
    return MeshData(vertices, faces, normals, uvs)


def interval_labels(values: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Per value, the index of the (disjoint) interval (low, high) that contains it, else -1."""
    inside = (values[:, None] > low[None]) & (values[:, None] < high[None])
    return np.where(inside.any(axis=1), inside.argmax(axis=1), -1)


# --------------------------------------------------------------------------- generators


class GroundPlaneParams(Params):
    size: PositiveFloat = 10.0
    uv_tiles: PositiveFloat = Field(default=1.0, description="how many times UVs repeat across the plane")

    def triangles(self) -> int:
        return 2


@GENERATORS.add(GroundPlaneParams)
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

    def triangles(self) -> int:
        branches = sum(self.branching**level for level in range(self.depth + 1))  # one 2-ring tube each
        leaves = self.branching**self.depth * self.leaves_per_tip  # one quad each
        return (2 * self.sides * branches if self.parts != "leaves" else 0) + (
            2 * leaves if self.parts != "branches" else 0
        )


@GENERATORS.add(FractalTreeParams)
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

    def triangles(self) -> int:
        return 4 * self.resolution * (self.resolution - 1)  # 2r columns: a fan at each pole, quads between


@GENERATORS.add(DisplacedSphereParams)
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

    def triangles(self) -> int:
        return 2 + 2 * self.strands * self.segments * self.sides  # the base, then each strand's quads


@GENERATORS.add(FurParams)
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


def resting_center(center: tuple[float, float, float] | None, height: float) -> np.ndarray:
    """`center`, or by default the point that puts an object of `height` on the y = 0 plane at the origin."""
    return np.array(center if center is not None else (0.0, height / 2.0, 0.0), dtype=np.float64)


class MengerSpongeParams(Params):
    level: Annotated[int, Field(ge=0, le=5, description="recursion depth; 0 is a plain cube")] = 3
    size: PositiveFloat = Field(default=1.0, description="edge length")
    center: Vec3 | None = Field(default=None, description="default (0, size / 2, 0): resting on y = 0")

    def triangles(self) -> int:
        squares = 6
        for n in range(self.level):
            squares = 20 * squares - 48 * 8**n
        return 2 * squares


@GENERATORS.add(MengerSpongeParams)
def menger_sponge(p: MengerSpongeParams) -> MeshData:
    """A Menger sponge: the cells of a 3^level grid with no base-3 place where two coordinates have a 1.

    The surface is the union of the kept cubes with every face between two kept cubes dropped: one
    closed, watertight, outward-facing surface of unit-cell squares (no T-junctions), flat normals.
    Squares per level follow Q(0) = 6, Q(n + 1) = 20 Q(n) - 48 * 8^n; triangles = 2 Q:
    level 1: 144, level 2: 2,112, level 3: 36,096, level 4: 672,768 (builds in about 0.5 s),
    level 5: 13,062,144 (about 15 s and 3 GB to build, more to compile: a stress asset only).
    """
    n = 3**p.level
    ones = (np.arange(n)[:, None] // 3 ** np.arange(p.level)) % 3 == 1  # (n, level) digit is 1
    count = ones[:, None, None, :].astype(np.uint8) + ones[None, :, None, :] + ones[None, None, :, :]
    occupied = ~(count >= 2).any(axis=-1)
    del count
    center = resting_center(p.center, p.size)
    steps = p.size * np.arange(n + 1) / n - p.size / 2.0
    return grid_surface(occupied, (center[0] + steps, center[1] + steps, center[2] + steps))


class HollowBoxParams(Params):
    size: PositiveFloat = Field(default=1.0, description="outer edge length")
    thickness: PositiveFloat = Field(default=0.01, description="wall thickness, less than size / 2")
    center: Vec3 | None = Field(default=None, description="default (0, size / 2, 0): resting on y = 0")

    @field_validator("thickness")
    @classmethod
    def _leaves_a_cavity(cls, thickness: float, info: ValidationInfo) -> float:
        size = info.data.get("size")
        if size is not None and thickness >= size / 2.0:
            raise ValueError(f"must be less than size / 2 = {size / 2.0:g} to leave a cavity")
        return thickness

    def triangles(self) -> int:
        return 24


@GENERATORS.add(HollowBoxParams)
def hollow_box(p: HollowBoxParams) -> MeshData:
    """A sealed thin-walled cube: a closed outward cube of edge `size` around a closed inward-facing cube.

    24 triangles. The cavity (edge `size - 2 thickness`) has no opening at all, so no light can reach
    it: any light seen from inside is a leak (Weier et al.'s closed-box test).
    """
    center = resting_center(p.center, p.size)
    unit = box()  # the cube [-1, 1]^3, outward
    outer = MeshData(unit.vertices * (p.size / 2.0) + center, unit.faces, unit.normals, unit.uvs)
    inner = MeshData(
        unit.vertices * (p.size / 2.0 - p.thickness) + center,
        unit.faces[:, ::-1].copy(),  # reversed winding: the inner surface faces into the cavity
        -unit.normals,
        unit.uvs,
    )
    return merge([outer, inner])


class ThinWallRoomsParams(Params):
    seed: Seed = 0
    cells_x: Annotated[int, Field(ge=1, le=6, description="rooms along x")] = 3
    cells_y: Annotated[int, Field(ge=1, le=6, description="storeys")] = 2
    cells_z: Annotated[int, Field(ge=1, le=6, description="rooms along z")] = 3
    size: PositiveFloat = Field(default=2.0, description="footprint edge length along x and z")
    storey_height: PositiveFloat = 0.5
    thickness: PositiveFloat = Field(
        default=0.02, description="wall, floor and roof thickness; at most a tenth of a room or storey"
    )
    windows: Annotated[
        FiniteFloat,
        Field(ge=0, le=1, description="chance that an outer wall panel (room x storey) has a window"),
    ] = 0.75
    doors: Annotated[
        FiniteFloat, Field(ge=0, le=1, description="chance that an inner wall panel has a doorway")
    ] = 0.5
    jitter: Annotated[
        FiniteFloat, Field(ge=0, le=0.2, description="random inner wall offsets, as a fraction of a room")
    ] = 0.1

    @field_validator("thickness")
    @classmethod
    def _thin(cls, thickness: float, info: ValidationInfo) -> float:
        d = info.data
        if {"cells_x", "cells_z", "size", "storey_height"} <= d.keys():
            room = d["size"] / max(d["cells_x"], d["cells_z"])
            limit = 0.1 * min(room, d["storey_height"])
            if thickness > limit:
                raise ValueError(f"must be at most a tenth of a room or storey ({limit:g})")
        return thickness

    def triangles(self) -> int:
        """At most two triangles per face of the grid `thin_wall_rooms` lays out (which faces bound the
        shell depends on the seed): per axis, two slab faces per wall and four window and door edges per
        room (x, z); two per floor and three window and door heights per storey (y)."""
        x, z = 6 * self.cells_x + 2, 6 * self.cells_z + 2
        y = 5 * self.cells_y + 2
        return 2 * (x * (y - 1) * (z - 1) + (x - 1) * y * (z - 1) + (x - 1) * (y - 1) * z)


WINDOW_WIDTH, WINDOW_SILL, WINDOW_TOP = 0.5, 0.3, 0.75  # of the room width; of the storey height
DOOR_WIDTH, DOOR_TOP = 0.3, 0.7


@GENERATORS.add(ThinWallRoomsParams)
def thin_wall_rooms(p: ThinWallRoomsParams) -> MeshData:
    """A building shell of cells_x x cells_z rooms on cells_y storeys, all thin axis-aligned slabs.

    Outer walls, inner walls, floors and a flat roof are slabs `thickness` thick (a hundredth of the
    default 2.0 footprint); it stands on y = 0, centred on the y axis, `size` wide and
    `cells_y * storey_height` tall. The seed jitters the inner walls and picks which outer wall
    panels get a window (an opening through the wall) and which inner wall panels a doorway.
    Slabs that meet are merged: the whole shell is one closed, watertight surface built on a
    rectilinear grid (`grid_surface`), so every slab is a closed solid and no faces hide inside
    a wall. Defaults give 7,776 triangles (seed 0); the largest grid (6 x 6 x 6) about 71k.
    """
    rng = np.random.default_rng(p.seed)
    t, h = p.thickness, p.storey_height

    def walls(rooms: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Wall slab bounds and room centres/widths along one horizontal axis."""
        lines = np.arange(rooms + 1, dtype=np.float64)
        lines[1:-1] += rng.uniform(-p.jitter, p.jitter, rooms - 1)
        lines = lines * (p.size / rooms) - p.size / 2.0
        low, high = lines - t / 2.0, lines + t / 2.0
        low[0], high[0], low[-1], high[-1] = lines[0], lines[0] + t, lines[-1] - t, lines[-1]
        return low, high, (lines[:-1] + lines[1:]) / 2.0, np.diff(lines)

    x_low, x_high, x_mid, x_width = walls(p.cells_x)
    z_low, z_high, z_mid, z_width = walls(p.cells_z)
    levels = h * np.arange(p.cells_y + 1, dtype=np.float64)
    y_low, y_high = levels - t / 2.0, levels + t / 2.0
    y_low[0], y_high[0], y_low[-1], y_high[-1] = 0.0, t, levels[-1] - t, levels[-1]
    storey = levels[:-1]
    sill, window_top = storey + WINDOW_SILL * h, storey + WINDOW_TOP * h
    door_bottom, door_top = y_high[:-1], storey + DOOR_TOP * h

    def bands(mid: np.ndarray, width: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray]:
        return mid - fraction * width / 2.0, mid + fraction * width / 2.0

    x_window, x_door = bands(x_mid, x_width, WINDOW_WIDTH), bands(x_mid, x_width, DOOR_WIDTH)
    z_window, z_door = bands(z_mid, z_width, WINDOW_WIDTH), bands(z_mid, z_width, DOOR_WIDTH)
    edges = (
        np.unique(np.concatenate([x_low, x_high, *x_window, *x_door])),
        np.unique(np.concatenate([y_low, y_high, sill, window_top, door_top])),
        np.unique(np.concatenate([z_low, z_high, *z_window, *z_door])),
    )
    mx, my, mz = ((e[:-1] + e[1:]) / 2.0 for e in edges)

    # which panels are open: tables over (wall, storey, room along the wall), drawn in full for any odds
    def panels(rooms_across: int, rooms_along: int, odds: float, outer: bool) -> np.ndarray:
        draw = rng.uniform(size=(rooms_across + 1, p.cells_y, rooms_along)) < odds
        wall = np.arange(rooms_across + 1)
        is_outer = (wall == 0) | (wall == rooms_across)
        return draw & (is_outer if outer else ~is_outer)[:, None, None]

    window_x = panels(p.cells_x, p.cells_z, p.windows, outer=True)  # walls across x, windows along z
    window_z = panels(p.cells_z, p.cells_x, p.windows, outer=True)
    door_x = panels(p.cells_x, p.cells_z, p.doors, outer=False)
    door_z = panels(p.cells_z, p.cells_x, p.doors, outer=False)

    wall_x = interval_labels(mx, x_low, x_high)
    wall_z = interval_labels(mz, z_low, z_high)
    floor = interval_labels(my, y_low, y_high)
    occupied = (wall_x >= 0)[:, None, None] | (floor >= 0)[None, :, None] | (wall_z >= 0)[None, None, :]

    def openings(table, wall, along, up, wall_axis):
        """Cells of a wall that a table's open panels remove; `along` and `up` label the panel bands."""
        labels = [wall, up, along]
        shapes = [(-1, 1, 1), (1, -1, 1), (1, 1, -1)]
        axes = [wall_axis, 1, 2 - wall_axis]  # grid axis of the wall index, storey and room along
        valid = np.ones((1, 1, 1), dtype=bool)
        index = []
        for label, axis in zip(labels, axes, strict=True):
            valid = valid & (label >= 0).reshape(shapes[axis])
            index.append(np.maximum(label, 0).reshape(shapes[axis]))
        return valid & table[index[0], index[1], index[2]]

    y_window = interval_labels(my, sill, window_top)
    y_door = interval_labels(my, door_bottom, door_top)
    occupied &= ~openings(window_x, wall_x, interval_labels(mz, *z_window), y_window, 0)
    occupied &= ~openings(door_x, wall_x, interval_labels(mz, *z_door), y_door, 0)
    occupied &= ~openings(window_z, wall_z, interval_labels(mx, *x_window), y_window, 2)
    occupied &= ~openings(door_z, wall_z, interval_labels(mx, *x_door), y_door, 2)
    return grid_surface(occupied, edges)
