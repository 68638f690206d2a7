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
    """Texels are chosen with probability proportional to the largest luminance the bilinear lookup takes
    over them (`_bilinear_maxima`) x sin(theta), then a point uniformly inside the texel; the solid-angle
    pdf divides by the texel's Jacobian 2 pi^2 sin(theta). Lookups and samples are compiled kernels
    (`lookup_rows`, `sample_rows`), which the light sampler and the path tracer also call on `tables` for
    their own rows."""

    def __init__(self, image: np.ndarray, rotation: np.ndarray):
        image = np.ascontiguousarray(image, dtype=np.float32)
        self.height, self.width = image.shape[:2]
        theta = (np.arange(self.height) + 0.5) / self.height * np.pi
        sin_theta = np.sin(theta)[:, None]
        texel_luminance = luminance(image.astype(np.float64))
        total = float((texel_luminance * sin_theta).sum())
        weights = _bilinear_maxima(texel_luminance) * sin_theta
        texel_prob = weights / max(float(weights.sum()), 1e-300)
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


def _bilinear_maxima(texels: np.ndarray) -> np.ndarray:
    """The largest value the bilinear lookup (`_bilinear`) takes over each texel of `texels` (H, W).

    Over the quarter of a texel towards a neighbour, the lookup blends the texel, its two edge neighbours
    on that side and the diagonal one; a bilinear function peaks at a corner of that quarter: the texel's
    centre (its own value), an edge's midpoint (the mean of two texels) or the texel's corner (the mean of
    four). Drawing texels by these maxima rather than by their own values bounds radiance / pdf (up to
    sin(theta) within a texel): by their own values, the half of a small bright disc's light that the
    lookup blends into its dim neighbours is reached only with their dim probability, rare huge samples
    (a sun disc of 5 texels: whole-image means of a floor at 16 spp from 0.78x to 1.31x the integral)."""
    up = np.concatenate([texels[:1], texels[:-1]])  # rows clamp at the poles, as `_corners`
    down = np.concatenate([texels[1:], texels[-1:]])
    maxima = texels.copy()
    for row in (up, down):
        maxima = np.maximum(maxima, (texels + row) / 2)
        for shift in (1, -1):  # columns wrap
            maxima = np.maximum(
                maxima, (texels + row + np.roll(texels, shift, 1) + np.roll(row, shift, 1)) / 4
            )
    for shift in (1, -1):
        maxima = np.maximum(maxima, (texels + np.roll(texels, shift, 1)) / 2)
    return maxima


def _guide(cdf: np.ndarray) -> np.ndarray:
    """As many cutpoints as entries: guide[j] = the number of entries of `cdf` <= j / len(cdf)."""
    return np.searchsorted(cdf, np.arange(len(cdf)) / len(cdf), side="right").astype(np.int32)


@kernels.scalar
def _lat_long(dx, dy, dz, rotation):
    """Lat-long (u, v) of world direction d in the map's frame
    (`workers.scene.generators.envmaps.direction_to_uv`), and sin(theta) (theta = pi v, from the direction:
    no third inverse-trigonometric call)."""
    x = dx * rotation[0, 0] + dy * rotation[1, 0] + dz * rotation[2, 0]
    y = dx * rotation[0, 1] + dy * rotation[1, 1] + dz * rotation[2, 1]
    z = dx * rotation[0, 2] + dy * rotation[1, 2] + dz * rotation[2, 2]
    length = max(math.sqrt(x * x + y * y + z * z), 1e-300)
    x, y, z = x / length, y / length, z / length
    u = math.atan2(x, -z) / (2.0 * math.pi)  # in [-0.5, 0.5]: u % 1.0, without fmod's library call
    if u < 0.0:
        u += 1.0
    if u >= 1.0:  # -tiny + 1.0 rounds to 1.0
        u = 0.0
    return u, math.acos(min(max(y, -1.0), 1.0)) / math.pi, math.sqrt(x * x + z * z)


@kernels.scalar
def _corners(height, width, u, v):
    """The texel rows y0, y1 and columns x0, x1 around (u, v) that `_bilinear` blends, and its weights' fx,
    fy: texel centres at (i + 0.5) / W, wrapping in u and clamped in v."""
    x = u * width - 0.5
    y = min(max(v * height - 0.5, 0.0), height - 1.0)
    x0f = math.floor(x)
    y0f = min(math.floor(y), height - 2) if height > 1 else 0.0
    x0 = int(x0f)  # >= -1: wrapped without an integer division
    x0 = x0 + width if x0 < 0 else x0
    y0 = int(y0f)
    return y0, min(y0 + 1, height - 1), x0, x0 + 1 if x0 + 1 < width else 0, x - x0f, y - y0f


@kernels.scalar
def _prefetch_corners(image, u, v):
    """Start loading the texels `_bilinear` reads at (u, v) (`kernels.prefetch`)."""
    height, width = image.shape[0], image.shape[1]
    y0, y1, x0, x1, _, _ = _corners(height, width, u, v)
    for y in (y0, y1):
        kernels.prefetch(image, (y * width + x0) * 3)
        kernels.prefetch(image, (y * width + x1) * 3 + 2)


@kernels.scalar
def _bilinear(image, u, v):
    """The map at (u, v), bilinear between texel centres, wrapping in u and clamped in v."""
    y0, y1, x0, x1, fx, fy = _corners(image.shape[0], image.shape[1], u, v)
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


BLOCK = 32  # rows whose table reads the staged kernels below issue together


@kernel
def lookup_rows(directions, rows, env):
    """(radiance (M, 3), solid-angle pdf (M,)) of the lat-long map along the world directions[rows], the pdf
    being that of `sample_rows` drawing them.

    In two stages over blocks of `BLOCK` rows, as `sample_rows`: first each direction's map coordinates
    (trigonometry) and a prefetch of the table entry and texels it reads (`kernels.prefetch`), then those
    reads, whose cache misses are then in flight together rather than each waiting behind the next row's
    trigonometry. The prefetches, measured as in `sample_rows`: random lookups 129-151 -> 83-88 ns."""
    height, width = env.image.shape[0], env.image.shape[1]
    m = len(rows)
    radiance, pdf = np.empty((m, 3)), np.empty(m)
    map_u, map_v, sin_of = np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK)
    for start in range(0, m, BLOCK):
        stop = min(start + BLOCK, m)
        for j in range(start, stop):
            i = rows[j]
            u, v, sin_of[j - start] = _lat_long(
                directions[i, 0], directions[i, 1], directions[i, 2], env.rotation
            )
            map_u[j - start], map_v[j - start] = u, v
            kernels.prefetch(
                env.col_cdf, min(int(v * height), height - 1) * width + min(int(u * width), width - 1)
            )
            _prefetch_corners(env.image, u, v)
        for j in range(start, stop):
            u, v, sin_theta = map_u[j - start], map_v[j - start], sin_of[j - start]
            col = min(int(u * width), width - 1)
            row = min(int(v * height), height - 1)
            pdf[j] = _texel_pdf(env, row, col) / sin_theta if sin_theta > 1e-12 else 0.0
            radiance[j, 0], radiance[j, 1], radiance[j, 2] = _bilinear(env.image, u, v)
    return radiance, pdf


@kernel
def sample_rows(u, rows, env, direction, pdf, radiance):
    """Directions drawn from the uniforms u[rows] (N, 2), written at `rows` of `direction` and `radiance`
    (the map there), and their solid-angle pdf multiplied into `pdf` (callers fill it with the light's
    selection probability, or 1).

    The row comes from u0, the column from u1, the point in the texel from what remains of each. A
    sample's reads depend on each other (the column guide, then the column cdf, then the texels), and each
    misses the cache on a large map: one sample at a time, each miss waits for the last (about 400 ns a
    sample on a 1024 x 512 map against 100 ns when the samples are coherent). So the work goes in stages
    over blocks of `BLOCK` rows, each stage a short loop that prefetches (`kernels.prefetch`) what the next
    stage reads of every row of the block: rows (then their column guides), column guides (then their cdf
    entries), columns (then their texels), texels, directions. The arithmetic is that of one sample at a
    time. Prefetching, measured (1024 x 512 map, random uniforms, one thread, CPU time, 3 alternating
    rounds): 120-140 -> 78-82 ns a sample, loads merely in flight together within a stage 120-140 ns."""
    height, width = env.image.shape[0], env.image.shape[1]
    row_cdf = env.row_cdf
    row_of, col_of = np.empty(BLOCK, np.int64), np.empty(BLOCK, np.int64)
    map_u, cos_of, sin_of = np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK)
    for start in range(0, len(rows), BLOCK):
        stop = min(start + BLOCK, len(rows))
        for j in range(start, stop):
            row = min(kernels.guided_search(row_cdf, env.row_guide, u[rows[j], 0]), height - 1)
            row_of[j - start] = row
            kernels.prefetch(env.col_guide, row * width + min(int(u[rows[j], 1] * width), width - 1))
        for j in range(start, stop):
            row = row_of[j - start]
            col = kernels.guide_start(env.col_guide[row], u[rows[j], 1])
            col_of[j - start] = col
            kernels.prefetch(env.col_cdf, row * width + max(col - 1, 0))
            kernels.prefetch(env.col_cdf, row * width + min(col, width - 1))
        for j in range(start, stop):
            u0, u1, row = u[rows[j], 0], u[rows[j], 1], row_of[j - start]
            lower = row_cdf[row - 1] if row > 0 else 0.0
            frac_v = min(max((u0 - lower) / max(row_cdf[row] - lower, 1e-300), 0.0), 1.0 - 1e-12)
            cdf = env.col_cdf[row]
            col = min(kernels.search_from(cdf, col_of[j - start], u1), width - 1)
            lower = cdf[col - 1] if col > 0 else 0.0
            frac_u = min(max((u1 - lower) / max(cdf[col] - lower, 1e-300), 0.0), 1.0 - 1e-12)
            col_of[j - start] = col
            map_u[j - start] = (col + frac_u) / width
            cos_of[j - start] = (row + frac_v) / height  # v until the next stage
            _prefetch_corners(env.image, map_u[j - start], cos_of[j - start])
        for j in range(start, stop):
            i, b = rows[j], j - start
            v = cos_of[b]
            cos_theta = math.cos(math.pi * v)
            sin_theta = math.sqrt(max(1.0 - cos_theta * cos_theta, 0.0))  # theta in [0, pi]: sin >= 0
            cos_of[b], sin_of[b] = cos_theta, sin_theta
            if sin_theta > 0:
                pdf[i] *= _texel_pdf(env, row_of[b], col_of[b]) / sin_theta
                radiance[i, 0], radiance[i, 1], radiance[i, 2] = _bilinear(env.image, map_u[b], v)
            else:
                pdf[i] *= 0.0
                radiance[i, 0], radiance[i, 1], radiance[i, 2] = 0.0, 0.0, 0.0
        rot = env.rotation
        for j in range(start, stop):
            i, b = rows[j], j - start
            phi, cos_theta, sin_theta = 2.0 * math.pi * map_u[b], cos_of[b], sin_of[b]
            lx, ly, lz = sin_theta * math.sin(phi), cos_theta, -sin_theta * math.cos(phi)
            direction[i, 0] = rot[0, 0] * lx + rot[0, 1] * ly + rot[0, 2] * lz
            direction[i, 1] = rot[1, 0] * lx + rot[1, 1] * ly + rot[1, 2] * lz
            direction[i, 2] = rot[2, 0] * lx + rot[2, 1] * ly + rot[2, 2] * lz


@kernel
def lookup(directions, env):
    """(radiance (N, 3), pdf (N,)) along world directions."""
    return lookup_rows(directions, np.arange(len(directions)), env)


@kernel
def sample(u, env):
    """(directions (N, 3), pdf (N,), radiance (N, 3)) drawn from uniforms (N, 2)."""
    n = len(u)
    directions, pdf, radiance = np.empty((n, 3)), np.ones(n), np.empty((n, 3))
    sample_rows(u, np.arange(n), env, directions, pdf, radiance)
    return directions, pdf, radiance
