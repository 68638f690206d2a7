"""Camera trajectories around the scene (Sec. 6): a training helix at the scene camera's distance, "near"
test views held out between its training points, and "far" test views on a second, closer, higher helix
that training never visits. Pixel rays go through pixel centres (the 1-spp G-buffer of Algorithm 1)."""

from __future__ import annotations

import math

import numpy as np

from workers.models.prt.config import CamerasConfig
from workers.render.camera import PinholeCamera
from workers.scene.spec import Camera

TRAIN, NEAR, FAR = "train", "near", "far"


def _on_helix(base: Camera, t: np.ndarray, config: CamerasConfig, scale: float, lift: float, size: int):
    target = np.asarray(base.target, np.float64)
    offset = np.asarray(base.position, np.float64) - target
    distance = float(np.linalg.norm(offset)) * scale
    azimuth0 = math.atan2(offset[0], offset[2])
    low, high = config.elevation_range
    cameras = []
    for ti in np.atleast_1d(t):
        azimuth = azimuth0 + math.radians(config.azimuth_range) * (ti - 0.5)
        elevation = math.radians(min(low + (high - low) * ti + lift, 85.0))
        direction = np.array(
            [
                math.cos(elevation) * math.sin(azimuth),
                math.sin(elevation),
                math.cos(elevation) * math.cos(azimuth),
            ]
        )
        position = tuple(float(c) for c in target + distance * direction)
        cameras.append(base.model_copy(update={"position": position, "width": size, "height": size}))
    return cameras


def trajectory_cameras(base: Camera, config: CamerasConfig, size: int) -> dict[str, list[Camera]]:
    n = config.train_views
    train_t = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
    # Near views sit half-way between training views, spread along the helix.
    picks = np.linspace(0, max(n - 2, 0), config.near_views).round().astype(int) if config.near_views else []
    near_t = np.array([(train_t[i] + train_t[min(i + 1, n - 1)]) / 2 for i in picks])
    far_t = (np.arange(config.far_views) + 0.5) / max(config.far_views, 1)
    return {
        TRAIN: _on_helix(base, train_t, config, 1.0, 0.0, size),
        NEAR: _on_helix(base, near_t, config, 1.0, 0.0, size) if len(near_t) else [],
        FAR: _on_helix(base, far_t, config, config.far_scale, 10.0, size) if len(far_t) else [],
    }


def pixel_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the centres of all pixels, row-major from the top-left."""
    pinhole = PinholeCamera(camera)
    py, px = np.mgrid[0 : pinhole.height, 0 : pinhole.width]
    return pinhole.rays(px.ravel() + 0.5, py.ravel() + 0.5)
