"""Environment lighting: a lat-long map with bilinear lookup and texel importance sampling,
or a constant background. Both answer radiance, sample and pdf in world space."""

from __future__ import annotations

import numpy as np

from workers.render.sampling import luminance, square_to_uniform_sphere
from workers.scene.envmaps import direction_to_uv, uv_to_direction


class EnvironmentMapLight:
    """Texels are chosen with probability proportional to luminance x sin(theta), then a point
    uniformly inside the texel; the solid-angle pdf divides by the texel's Jacobian 2 pi^2 sin(theta)."""

    def __init__(self, image: np.ndarray, rotation: np.ndarray):
        self.image = np.ascontiguousarray(image, dtype=np.float64)
        self.height, self.width = image.shape[:2]
        self.rotation = np.asarray(rotation, dtype=np.float64)  # local -> world
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
        uv = direction_to_uv(directions @ self.rotation)
        x = uv[:, 0] * self.width - 0.5
        y = np.clip(uv[:, 1] * self.height - 0.5, 0.0, self.height - 1.0)
        x0 = np.floor(x)
        y0 = np.minimum(np.floor(y), self.height - 2) if self.height > 1 else np.zeros_like(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0 = x0.astype(np.int64) % self.width
        x1 = (x0 + 1) % self.width
        y0 = y0.astype(np.int64)
        y1 = np.minimum(y0 + 1, self.height - 1)
        im = self.image
        top = im[y0, x0] * (1 - fx) + im[y0, x1] * fx
        bottom = im[y1, x0] * (1 - fx) + im[y1, x1] * fx
        return top * (1 - fy) + bottom * fy

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World directions and their solid-angle pdfs from uniforms (N, 2)."""
        idx = np.minimum(np.searchsorted(self.cdf, u[:, 0], side="right"), len(self.cdf) - 1)
        lower = np.where(idx > 0, self.cdf[np.maximum(idx - 1, 0)], 0.0)
        frac = np.clip((u[:, 0] - lower) / np.maximum(self.cdf[idx] - lower, 1e-300), 0.0, 1.0 - 1e-12)
        row, col = np.divmod(idx, self.width)
        uv = np.stack([(col + frac) / self.width, (row + u[:, 1]) / self.height], axis=1)
        local = uv_to_direction(uv[:, 0], uv[:, 1])
        sin_theta = np.sin(uv[:, 1] * np.pi)
        pdf = self.texel_prob[idx] * self.width * self.height / np.maximum(2 * np.pi**2 * sin_theta, 1e-300)
        return local @ self.rotation.T, np.where(sin_theta > 0, pdf, 0.0)

    def pdf(self, directions: np.ndarray) -> np.ndarray:
        uv = direction_to_uv(directions @ self.rotation)
        col = np.minimum((uv[:, 0] * self.width).astype(np.int64), self.width - 1)
        row = np.minimum((uv[:, 1] * self.height).astype(np.int64), self.height - 1)
        sin_theta = np.sin(uv[:, 1] * np.pi)
        p = self.texel_prob[row * self.width + col] * self.width * self.height
        return np.where(sin_theta > 1e-12, p / np.maximum(2 * np.pi**2 * sin_theta, 1e-300), 0.0)


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
