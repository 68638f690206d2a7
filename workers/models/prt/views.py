"""Camera trajectories around the scene (Sec. 6): a training helix at the scene camera's distance, "near"
test views held out between its training points, and "far" test views on a second, closer, higher helix
that training never visits. With `train_band` > 0 the training views leave the one helix and spread over
the band between it and the far helix (the paper spreads its training cameras over spheres), each at its own
fraction of the way, so training sees the surface from the distances and elevations far views have. Pixel
rays go through pixel centres (the 1-spp G-buffer of Algorithm 1)."""

from __future__ import annotations

import math

import numpy as np

from workers.models.prt.config import CamerasConfig
from workers.render.camera import PinholeCamera
from workers.scene.format.spec import Camera

TRAIN, NEAR, FAR = "train", "near", "far"


def _on_helix(base: Camera, t: np.ndarray, config: CamerasConfig, scale, lift, size: int):
    """Cameras at helix parameters `t`, at `scale` times the scene camera's distance and `lift` degrees above
    the helix (scalars or one per camera)."""
    target = np.asarray(base.target, np.float64)
    offset = np.asarray(base.position, np.float64) - target
    t = np.atleast_1d(t)
    scales, lifts = np.broadcast_to(scale, t.shape), np.broadcast_to(lift, t.shape)
    azimuth0 = math.atan2(offset[0], offset[2])
    low, high = config.elevation_range
    cameras = []
    for ti, scale, lift in zip(t, scales, lifts, strict=True):
        distance = float(np.linalg.norm(offset)) * scale
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


def _radical_inverse(i: np.ndarray) -> np.ndarray:
    """Van der Corput's base-2 sequence: consecutive training views land far apart across the band."""
    out, weight = np.zeros(len(i)), 0.5
    i = i.copy()
    while i.any():
        out += weight * (i & 1)
        i >>= 1
        weight /= 2
    return out


def trajectory_cameras(base: Camera, config: CamerasConfig, size: int) -> dict[str, list[Camera]]:
    n = config.train_views
    train_t = np.linspace(0.0, 1.0, n) if n > 1 else np.array([0.5])
    # Near views sit half-way between training views, spread along the helix.
    picks = np.linspace(0, max(n - 2, 0), config.near_views).round().astype(int) if config.near_views else []
    near_t = np.array([(train_t[i] + train_t[min(i + 1, n - 1)]) / 2 for i in picks])
    far_t = (np.arange(config.far_views) + 0.5) / max(config.far_views, 1)
    band = config.train_band * _radical_inverse(np.arange(n))  # of the way from the helix to the far one
    train_scale = 1 + (config.far_scale - 1) * band
    return {
        TRAIN: _on_helix(base, train_t, config, train_scale, config.far_lift * band, size),
        NEAR: _on_helix(base, near_t, config, 1.0, 0.0, size) if len(near_t) else [],
        FAR: _on_helix(base, far_t, config, config.far_scale, config.far_lift, size) if len(far_t) else [],
    }


def pixel_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rays through the centres of all pixels, row-major from the top-left."""
    pinhole = PinholeCamera(camera)
    py, px = np.mgrid[0 : pinhole.height, 0 : pinhole.width]
    return pinhole.rays(px.ravel() + 0.5, py.ravel() + 0.5)
