"""A default view of a box: the camera an importer gives a file without one, and a served model's view."""

from __future__ import annotations

import math

import numpy as np

from workers.scene.format.spec import Camera

FRAMING_DIRECTION = np.array([0.45, 0.35, 1.0])  # from the model's centre towards a default camera


def framing_camera(bounds: np.ndarray, fov: float = 40.0) -> Camera:
    """A camera that sees the box `bounds` (2, 3) whole, from the front, above and to the right."""
    lo, hi = np.asarray(bounds, np.float64)
    center, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-9)
    distance = 1.1 * radius / math.sin(math.radians(fov) / 2)
    direction = FRAMING_DIRECTION / np.linalg.norm(FRAMING_DIRECTION)
    position = center + distance * direction
    return Camera(position=tuple(position.tolist()), target=tuple(center.tolist()), fov=fov)
