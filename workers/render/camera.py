"""Pinhole camera rays; pixel (0, 0) is the top-left corner, image x runs along the camera's right."""

from __future__ import annotations

import math

import numpy as np

from workers.render.sampling import normalize
from workers.scene.spec import Camera


class PinholeCamera:
    def __init__(self, camera: Camera, width: int | None = None, height: int | None = None):
        self.width = width or camera.width
        self.height = height or camera.height
        self.origin = np.asarray(camera.position, dtype=np.float64)
        forward = normalize(np.asarray(camera.target, float) - self.origin)
        right = normalize(np.cross(forward, np.asarray(camera.up, float)))
        up = np.cross(right, forward)
        tan_half = math.tan(math.radians(camera.fov) / 2)
        self.forward = forward
        self.right = right * tan_half * self.width / self.height
        self.up = up * tan_half
        # A pixel's angle at the image centre: the cone each camera ray stands for, for texture LOD
        # (Akenine-Moeller et al. 2019, eq. 30).
        self.spread = math.atan(2.0 * tan_half / self.height)

    def rays(self, px: np.ndarray, py: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays through continuous pixel coordinates (px right, py down, in pixels)."""
        x = 2.0 * px / self.width - 1.0
        y = 1.0 - 2.0 * py / self.height
        d = self.forward + x[:, None] * self.right + y[:, None] * self.up
        return np.broadcast_to(self.origin, d.shape).copy(), normalize(d)
