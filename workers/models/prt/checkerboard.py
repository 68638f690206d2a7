"""Checkerboard shading of the indirect light: the network runs at half of a frame's pixels, those with
x + y even, and each other pixel takes the mean of its shaded 4-neighbours on the same surface (the same
object, normals within `SAME_SURFACE_COS`). A pixel with no such neighbour (a silhouette, a thin part) is
shaded as well. Indirect light varies slowly across a surface, so this halves the network's time, the
frame's largest cost on a CPU, for a small error (measured in `PrtConfig.checkerboard`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.models.prt.gbuffer import SurfaceInputs

SAME_SURFACE_COS = 0.9  # neighbours whose normals differ by more than ~25 degrees are another surface
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1))


def _shifted(array: np.ndarray, dy: int, dx: int, outside) -> np.ndarray:
    """array[y + dy, x + dx] at (y, x) over the image's first two axes, `outside` beyond its edges."""
    out = np.full_like(array, outside)
    h, w = array.shape[:2]
    out[max(-dy, 0) : h - max(dy, 0), max(-dx, 0) : w - max(dx, 0)] = array[
        max(dy, 0) : h - max(-dy, 0), max(dx, 0) : w - max(-dx, 0)
    ]
    return out


@dataclass
class Checkerboard:
    """A frame's checkerboard: `shaded` (N,) the modelled pixels the network evaluates (the checkerboard's
    and those with no neighbour to take a value from); `weights` (4, H, W) whether a pixel may take each
    4-neighbour's value (the neighbour is on the checkerboard, modelled, and on the same surface)."""

    shaded: np.ndarray
    weights: np.ndarray
    modelled: np.ndarray

    def fill(self, values: np.ndarray) -> np.ndarray:
        """`values` (N, 3), set at the `shaded` pixels, with every other modelled pixel the mean of its
        same-surface neighbours on the checkerboard."""
        weights = self.weights.astype(values.dtype)
        height, width = weights.shape[1:]
        image = values.reshape(height, width, -1)
        total = sum(
            w[..., None] * _shifted(image, dy, dx, 0)
            for w, (dy, dx) in zip(weights, _NEIGHBOURS, strict=True)
        )
        count = weights.sum(axis=0)[..., None]
        filled = (total / np.maximum(count, 1)).reshape(values.shape)
        out = values.copy()
        rest = self.modelled & ~self.shaded
        out[rest] = filled[rest]
        return out


def checkerboard(inputs: SurfaceInputs, modelled: np.ndarray, height: int, width: int) -> Checkerboard:
    """The checkerboard of a frame's G-buffer `inputs` (N = height x width pixels) over its `modelled`
    pixels."""
    y, x = np.mgrid[0:height, 0:width]
    even = (y + x) % 2 == 0
    on = modelled.reshape(height, width) & even
    object_id = inputs.object_id.reshape(height, width)
    normal = inputs.normal.reshape(height, width, 3)
    weights = []
    for dy, dx in _NEIGHBOURS:
        same_object = _shifted(object_id, dy, dx, -1) == object_id
        aligned = np.sum(_shifted(normal, dy, dx, 0.0) * normal, axis=-1) > SAME_SURFACE_COS
        weights.append(_shifted(on, dy, dx, False) & same_object & aligned)
    weights = np.stack(weights)
    orphan = ~weights.any(axis=0)
    return Checkerboard(modelled & (even | orphan).ravel(), weights, modelled)
