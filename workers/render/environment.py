"""Environment lighting: a lat-long map with bilinear lookup and texel importance sampling,
or a constant background. Both answer radiance, sample and pdf in world space."""

from __future__ import annotations

import math

import numpy as np

from workers.render import kernels
from workers.render.jit import njit
from workers.render.sampling import luminance, square_to_uniform_sphere

kernel = njit(cache=True, nogil=True, fastmath=False)


class EnvironmentMapLight:
    """Texels are chosen with probability proportional to luminance x sin(theta), then a point
    uniformly inside the texel; the solid-angle pdf divides by the texel's Jacobian 2 pi^2 sin(theta).
    Lookups and samples are compiled kernels (one pass over the directions)."""

    def __init__(self, image: np.ndarray, rotation: np.ndarray):
        self.image = np.ascontiguousarray(image, dtype=np.float64)
        self.height, self.width = image.shape[:2]
        self.rotation = np.ascontiguousarray(rotation, dtype=np.float64)  # local -> world
        theta = (np.arange(self.height) + 0.5) / self.height * np.pi
        weights = luminance(self.image) * np.sin(theta)[:, None]
        self.total_weight = float(weights.sum())
        self.texel_prob = (weights / max(self.total_weight, 1e-300)).ravel()
        self.cdf = np.cumsum(self.texel_prob)
        self.cdf /= max(self.cdf[-1], 1e-300)
        self.mean_radiance = float((luminance(self.image) * np.sin(theta)[:, None]).sum())
        self.mean_radiance *= np.pi / self.height * 2 * np.pi / self.width / (4 * np.pi)

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated radiance seen along world directions (texel centres at (i + 0.5) / W)."""
        return _radiance(_f64(directions), self.rotation, self.image)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World directions and their solid-angle pdfs from uniforms (N, 2)."""
        return _sample(_f64(u), self.cdf, self.texel_prob, self.width, self.height, self.rotation)

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        return _pdf(_f64(directions), self.rotation, self.texel_prob, self.width, self.height)


class ConstantEnvironment:
    """Uniform radiance from every direction, sampled uniformly over the sphere."""

    def __init__(self, radiance):
        self.value = np.asarray(radiance, dtype=np.float64)
        self.mean_radiance = float(luminance(self.value))

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        return np.broadcast_to(self.value, (len(directions), 3))

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return square_to_uniform_sphere(u), np.full(len(u), 1.0 / (4 * np.pi))

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        return np.full(len(directions), 1.0 / (4 * np.pi))


def _f64(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


@kernels.scalar
def _lat_long(d, rotation):
    """Lat-long (u, v) of world direction d in the map's frame (`workers.scene.envmaps.direction_to_uv`)."""
    x = d[0] * rotation[0, 0] + d[1] * rotation[1, 0] + d[2] * rotation[2, 0]
    y = d[0] * rotation[0, 1] + d[1] * rotation[1, 1] + d[2] * rotation[2, 1]
    z = d[0] * rotation[0, 2] + d[1] * rotation[1, 2] + d[2] * rotation[2, 2]
    length = max(math.sqrt(x * x + y * y + z * z), 1e-300)
    x, y, z = x / length, y / length, z / length
    u = math.atan2(x, -z) / (2.0 * math.pi) % 1.0
    if u >= 1.0:  # -tiny % 1.0 rounds to 1.0
        u = 0.0
    return u, math.acos(min(max(y, -1.0), 1.0)) / math.pi


@kernel
def _radiance(directions, rotation, image):
    height, width = image.shape[0], image.shape[1]
    out = np.empty((len(directions), 3))
    for i in range(len(directions)):
        u, v = _lat_long(directions[i], rotation)
        x = u * width - 0.5
        y = min(max(v * height - 0.5, 0.0), height - 1.0)
        x0f = math.floor(x)
        y0f = min(math.floor(y), height - 2) if height > 1 else 0.0
        fx, fy = x - x0f, y - y0f
        x0 = int(x0f) % width
        x1 = (x0 + 1) % width
        y0 = int(y0f)
        y1 = min(y0 + 1, height - 1)
        for c in range(3):
            top = image[y0, x0, c] * (1 - fx) + image[y0, x1, c] * fx
            bottom = image[y1, x0, c] * (1 - fx) + image[y1, x1, c] * fx
            out[i, c] = top * (1 - fy) + bottom * fy
    return out


@kernel
def _sample(u, cdf, texel_prob, width, height, rotation):
    n = len(u)
    directions, pdf = np.empty((n, 3)), np.zeros(n)
    for i in range(n):
        idx = min(kernels.search_right(cdf, u[i, 0]), len(cdf) - 1)
        lower = cdf[idx - 1] if idx > 0 else 0.0
        frac = min(max((u[i, 0] - lower) / max(cdf[idx] - lower, 1e-300), 0.0), 1.0 - 1e-12)
        row, col = idx // width, idx % width
        phi = 2.0 * math.pi * ((col + frac) / width)
        theta = math.pi * ((row + u[i, 1]) / height)
        sin_theta = math.sin(theta)
        local = (sin_theta * math.sin(phi), math.cos(theta), -sin_theta * math.cos(phi))
        for r in range(3):
            directions[i, r] = (
                rotation[r, 0] * local[0] + rotation[r, 1] * local[1] + rotation[r, 2] * local[2]
            )
        if sin_theta > 0:
            pdf[i] = texel_prob[idx] * width * height / max(2 * math.pi**2 * sin_theta, 1e-300)
    return directions, pdf


@kernel
def _pdf(directions, rotation, texel_prob, width, height):
    out = np.zeros(len(directions))
    for i in range(len(directions)):
        u, v = _lat_long(directions[i], rotation)
        col = min(int(u * width), width - 1)
        row = min(int(v * height), height - 1)
        sin_theta = math.sin(v * math.pi)
        if sin_theta > 1e-12:
            out[i] = texel_prob[row * width + col] * width * height / max(2 * math.pi**2 * sin_theta, 1e-300)
    return out
