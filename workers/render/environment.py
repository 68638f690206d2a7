"""Environment lighting: a lat-long map with bilinear lookup and texel importance sampling,
or a constant background. Both answer radiance, sample and pdf in world space."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from workers.render import kernels
from workers.render.jit import njit
from workers.render.sampling import luminance, square_to_uniform_sphere

kernel = njit(cache=True, nogil=True, fastmath=False)


class EnvironmentTables(NamedTuple):
    """A lat-long map as the compiled kernels read it (one typed argument); `NO_MAP` has no texels.

    Texels are drawn in two steps, a row by its marginal probability, then a column of that row, each by
    a guided search (`workers.render.kernels.guided_search`): with a binary search over a row, the
    dependent cache misses cost a sample of a 1024 x 512 map more than all the rest of its work.
    A texel's probability is read off the two cdfs (the entries the sample's searches just loaded) rather
    than from a table of its own, one cache miss fewer per sample.
    The image is float32, the precision of the maps as loaded; interpolation and sampling are float64."""

    image: np.ndarray  # (H, W, 3) float32
    rotation: np.ndarray  # (3, 3) local -> world
    row_cdf: np.ndarray  # (H,) cumulative probability of the rows, last entry 1
    row_guide: np.ndarray  # (H,) int32 cutpoints of row_cdf
    col_cdf: np.ndarray  # (H, W) cumulative probability of the columns of each row, last entries 1
    col_guide: np.ndarray  # (H, W) int32 cutpoints of each row of col_cdf
    pdf_scale: float  # W H / (2 pi^2): a texel's probability times this over sin(theta) is the pdf; 0: black


NO_MAP = EnvironmentTables(
    np.zeros((0, 0, 3), np.float32),
    np.eye(3),
    np.zeros(0),
    np.zeros(0, np.int32),
    np.zeros((0, 0)),
    np.zeros((0, 0), np.int32),
    0.0,
)


class EnvironmentMapLight:
    """Texels are chosen with probability proportional to luminance x sin(theta), then a point
    uniformly inside the texel; the solid-angle pdf divides by the texel's Jacobian 2 pi^2 sin(theta).
    Lookups and samples are compiled kernels (one pass over the directions), which the light sampler and
    the path tracer also call row by row on `tables`."""

    def __init__(self, image: np.ndarray, rotation: np.ndarray):
        image = np.ascontiguousarray(image, dtype=np.float32)
        self.height, self.width = image.shape[:2]
        theta = (np.arange(self.height) + 0.5) / self.height * np.pi
        weights = luminance(image.astype(np.float64)) * np.sin(theta)[:, None]
        total = float(weights.sum())
        texel_prob = weights / max(total, 1e-300)
        row_cdf = _cdf(texel_prob.sum(axis=1))
        col_cdf = np.stack([_cdf(row) for row in texel_prob])
        self.tables = EnvironmentTables(
            image,
            np.ascontiguousarray(rotation, dtype=np.float64),
            row_cdf,
            _guide(row_cdf),
            col_cdf,
            np.stack([_guide(row) for row in col_cdf]),
            self.width * self.height / (2 * np.pi**2) if total > 0 else 0.0,
        )
        self.mean_radiance = total * np.pi / self.height * 2 * np.pi / self.width / (4 * np.pi)

    @property
    def image(self) -> np.ndarray:
        return self.tables.image

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated radiance seen along world directions (texel centres at (i + 0.5) / W)."""
        return lookup(_f64(directions), self.tables)[0]

    def radiance_and_pdf(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`radiance` and `pdf` of the directions in one pass (each direction's map coordinates once)."""
        return lookup(_f64(directions), self.tables)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World directions and their solid-angle pdfs from uniforms (N, 2)."""
        directions, pdf, _ = sample(_f64(u), self.tables)
        return directions, pdf

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        return lookup(_f64(directions), self.tables)[1]


class ConstantEnvironment:
    """Uniform radiance from every direction, sampled uniformly over the sphere."""

    def __init__(self, radiance):
        self.value = np.asarray(radiance, dtype=np.float64)
        self.mean_radiance = float(luminance(self.value))

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        return np.broadcast_to(self.value, (len(directions), 3))

    def radiance_and_pdf(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.radiance(directions), self.pdf(directions)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return square_to_uniform_sphere(u), np.full(len(u), 1.0 / (4 * np.pi))

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        return np.full(len(directions), 1.0 / (4 * np.pi))


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _cdf(prob: np.ndarray) -> np.ndarray:
    """Cumulative sums of `prob` ending at exactly 1 (uniform where `prob` sums to 0: never drawn then)."""
    total = prob.sum()
    if not total > 0:
        prob = np.ones_like(prob)
    cdf = np.minimum(np.cumsum(prob) / prob.sum(), 1.0)  # rounding must not lift an entry above the last
    cdf[-1] = 1.0
    return cdf


def _guide(cdf: np.ndarray) -> np.ndarray:
    """As many cutpoints as entries: guide[j] = the number of entries of `cdf` <= j / len(cdf)."""
    return np.searchsorted(cdf, np.arange(len(cdf)) / len(cdf), side="right").astype(np.int32)


@kernels.scalar
def _lat_long(dx, dy, dz, rotation):
    """Lat-long (u, v) of world direction d in the map's frame (`workers.scene.envmaps.direction_to_uv`),
    and sin(theta) (theta = pi v, from the direction: no third inverse-trigonometric call)."""
    x = dx * rotation[0, 0] + dy * rotation[1, 0] + dz * rotation[2, 0]
    y = dx * rotation[0, 1] + dy * rotation[1, 1] + dz * rotation[2, 1]
    z = dx * rotation[0, 2] + dy * rotation[1, 2] + dz * rotation[2, 2]
    length = max(math.sqrt(x * x + y * y + z * z), 1e-300)
    x, y, z = x / length, y / length, z / length
    u = math.atan2(x, -z) / (2.0 * math.pi) % 1.0
    if u >= 1.0:  # -tiny % 1.0 rounds to 1.0
        u = 0.0
    return u, math.acos(min(max(y, -1.0), 1.0)) / math.pi, math.sqrt(x * x + z * z)


@kernels.scalar
def _bilinear(image, u, v):
    """The map at (u, v), bilinear between texel centres, wrapping in u and clamped in v."""
    height, width = image.shape[0], image.shape[1]
    x = u * width - 0.5
    y = min(max(v * height - 0.5, 0.0), height - 1.0)
    x0f = math.floor(x)
    y0f = min(math.floor(y), height - 2) if height > 1 else 0.0
    fx, fy = x - x0f, y - y0f
    x0 = int(x0f) % width
    x1 = (x0 + 1) % width
    y0 = int(y0f)
    y1 = min(y0 + 1, height - 1)
    w00, w01, w10, w11 = (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy
    r = w00 * image[y0, x0, 0] + w01 * image[y0, x1, 0] + w10 * image[y1, x0, 0] + w11 * image[y1, x1, 0]
    g = w00 * image[y0, x0, 1] + w01 * image[y0, x1, 1] + w10 * image[y1, x0, 1] + w11 * image[y1, x1, 1]
    b = w00 * image[y0, x0, 2] + w01 * image[y0, x1, 2] + w10 * image[y1, x0, 2] + w11 * image[y1, x1, 2]
    return r, g, b


@kernels.scalar
def _texel_pdf(env, row, col):
    """The probability of drawing texel (row, col), times `pdf_scale`."""
    row_lower = env.row_cdf[row - 1] if row > 0 else 0.0
    col_lower = env.col_cdf[row, col - 1] if col > 0 else 0.0
    return (env.row_cdf[row] - row_lower) * (env.col_cdf[row, col] - col_lower) * env.pdf_scale


@kernels.scalar
def direction_lookup(dx, dy, dz, env):
    """Radiance along a world direction and the solid-angle pdf of `sample_one` drawing it."""
    u, v, sin_theta = _lat_long(dx, dy, dz, env.rotation)
    height, width = env.image.shape[0], env.image.shape[1]
    col = min(int(u * width), width - 1)
    row = min(int(v * height), height - 1)
    pdf = _texel_pdf(env, row, col) / sin_theta if sin_theta > 1e-12 else 0.0
    r, g, b = _bilinear(env.image, u, v)
    return r, g, b, pdf


@kernels.scalar
def sample_one(u0, u1, env):
    """A world direction drawn from uniforms (u0, u1): the row from u0, the column from u1, the point in the
    texel from what remains of each. Returns the direction, its solid-angle pdf and the radiance there."""
    height, width = env.image.shape[0], env.image.shape[1]
    row = min(kernels.guided_search(env.row_cdf, env.row_guide, u0), height - 1)
    lower = env.row_cdf[row - 1] if row > 0 else 0.0
    frac_v = min(max((u0 - lower) / max(env.row_cdf[row] - lower, 1e-300), 0.0), 1.0 - 1e-12)
    cdf = env.col_cdf[row]
    col = min(kernels.guided_search(cdf, env.col_guide[row], u1), width - 1)
    lower = cdf[col - 1] if col > 0 else 0.0
    frac_u = min(max((u1 - lower) / max(cdf[col] - lower, 1e-300), 0.0), 1.0 - 1e-12)
    u, v = (col + frac_u) / width, (row + frac_v) / height
    phi, cos_theta = 2.0 * math.pi * u, math.cos(math.pi * v)
    sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))  # theta in [0, pi]: sin >= 0
    lx, ly, lz = sin_theta * math.sin(phi), cos_theta, -sin_theta * math.cos(phi)
    rot = env.rotation
    dx = rot[0, 0] * lx + rot[0, 1] * ly + rot[0, 2] * lz
    dy = rot[1, 0] * lx + rot[1, 1] * ly + rot[1, 2] * lz
    dz = rot[2, 0] * lx + rot[2, 1] * ly + rot[2, 2] * lz
    if not sin_theta > 0:
        return dx, dy, dz, 0.0, 0.0, 0.0, 0.0
    r, g, b = _bilinear(env.image, u, v)
    return dx, dy, dz, _texel_pdf(env, row, col) / sin_theta, r, g, b


@kernel
def lookup(directions, env):
    """(radiance (N, 3), pdf (N,)) along world directions."""
    n = len(directions)
    radiance, pdf = np.empty((n, 3)), np.empty(n)
    for i in range(n):
        d = directions[i]
        radiance[i, 0], radiance[i, 1], radiance[i, 2], pdf[i] = direction_lookup(d[0], d[1], d[2], env)
    return radiance, pdf


@kernel
def sample(u, env):
    """(directions (N, 3), pdf (N,), radiance (N, 3)) drawn from uniforms (N, 2)."""
    n = len(u)
    directions, pdf, radiance = np.empty((n, 3)), np.empty(n), np.empty((n, 3))
    for i in range(n):
        dx, dy, dz, p, r, g, b = sample_one(u[i, 0], u[i, 1], env)
        directions[i, 0], directions[i, 1], directions[i, 2], pdf[i] = dx, dy, dz, p
        radiance[i, 0], radiance[i, 1], radiance[i, 2] = r, g, b
    return directions, pdf, radiance
