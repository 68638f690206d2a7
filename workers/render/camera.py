"""Pinhole camera rays; pixel (0, 0) is the top-left corner, image x runs along the camera's right."""

from __future__ import annotations

import math

import numpy as np

from workers.render.jit import njit
from workers.render.sampling import normalize
from workers.scene.format.spec import Camera


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
        """Rays through continuous pixel coordinates (px right, py down, in pixels); one compiled pass."""
        return _rays(
            np.ascontiguousarray(px, np.float64), np.ascontiguousarray(py, np.float64), self.width,
            self.height, self.origin, self.forward, self.right, self.up,
        )  # fmt: skip


@njit(cache=True, nogil=True, fastmath=False)
def _rays(px, py, width, height, origin, forward, right, up):
    n = len(px)
    origins, directions = np.empty((n, 3)), np.empty((n, 3))
    for i in range(n):
        x = 2.0 * px[i] / width - 1.0
        y = 1.0 - 2.0 * py[i] / height
        dx = forward[0] + x * right[0] + y * up[0]
        dy = forward[1] + x * right[1] + y * up[1]
        dz = forward[2] + x * right[2] + y * up[2]
        length = max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-30)
        origins[i, 0], origins[i, 1], origins[i, 2] = origin[0], origin[1], origin[2]
        directions[i, 0], directions[i, 1], directions[i, 2] = dx / length, dy / length, dz / length
    return origins, directions
